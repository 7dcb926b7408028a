"""``/v1/docs``: Swagger UI served by the daemon itself, so it renders on a cell with no
internet. The assets (Swagger UI 5's bundle and stylesheet, Apache-2.0) come from the
``fastapi-offline`` package, which ships them for exactly this; FastAPI's own
``get_swagger_ui_html`` writes the page around them."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

ASSETS_URL = "/v1/docs/assets"
router = APIRouter()


@router.get("/v1/docs", include_in_schema=False)
def swagger_ui() -> HTMLResponse:
    """The interactive API documentation, every asset from this daemon."""
    return get_swagger_ui_html(
        openapi_url="/v1/openapi.json",
        title="lasercal daemon: API",
        swagger_js_url=f"{ASSETS_URL}/swagger-ui-bundle.js",
        swagger_css_url=f"{ASSETS_URL}/swagger-ui.css",
        swagger_favicon_url=f"{ASSETS_URL}/favicon.png",
    )


def mount_assets(app: FastAPI) -> None:
    """Serve the Swagger UI files under ``ASSETS_URL`` (before the page's catch-all mount)."""
    assets = Path(str(resources.files("fastapi_offline"))) / "static"
    app.mount(ASSETS_URL, StaticFiles(directory=assets), name="docs-assets")
