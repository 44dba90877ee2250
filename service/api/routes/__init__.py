"""HTTP and WebSocket routes: one APIRouter per resource, thin over the flows in ``service``."""
