"""What the service does with a request: observations (confidence, control bounds, the agent's
FRT version), collision checks, contours and the stateless FRT, over ``reach`` and the runtime."""
