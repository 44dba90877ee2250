"""FRT as a service: confidence-aware forward reachable tubes over HTTP and WebSocket."""
