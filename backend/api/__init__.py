"""HTTP and websocket routes: thin, pydantic at the edge, database access through backend.store."""
