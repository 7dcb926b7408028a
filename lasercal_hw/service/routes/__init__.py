"""The daemon's HTTP routes: one ``APIRouter`` per resource, the service reached through
FastAPI dependencies (``deps``), the service's errors answered with their status
(``problems``). Only this package speaks HTTP."""
