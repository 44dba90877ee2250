"""The HTTP face: the app, its routes, request and response schemas, errors, middleware, auth,
limits and the WebSocket protocol. Routes validate, call a flow and shape the answer."""
