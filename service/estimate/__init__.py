"""POST /estimate, POST /plan and WS /estimate/stream: fit.py (the state from tracked points), aim.py (where to put
the guide), schemas.py and routes.py (the HTTP side)."""
