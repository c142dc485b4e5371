"""The HTTP and WebSocket edge: the guards in front of uvicorn, TLS, tokens and roles, the audit."""
