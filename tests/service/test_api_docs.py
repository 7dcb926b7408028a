"""``/v1/docs`` needs nothing from the internet: the page and every asset it loads come from
the daemon (the browser test renders it with the network cut off: tests/browser/)."""

from __future__ import annotations

import re

from fastapi.testclient import TestClient

from tests.service.test_service import client, engine  # noqa: F401  (the daemon fixtures)


def test_swagger_ui_loads_only_assets_the_daemon_serves(client: TestClient) -> None:  # noqa: F811
    page = client.get("/v1/docs")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    urls = re.findall(r"""(?:src|href|url)\s*[:=]\s*['"]([^'"]+)['"]""", page.text)
    assert urls and not [u for u in urls if "://" in u or u.startswith("//")], urls
    assert "/v1/openapi.json" in urls
    for url in urls:
        asset = client.get(url)
        assert asset.status_code == 200, url
    bundle = client.get("/v1/docs/assets/swagger-ui-bundle.js")
    assert len(bundle.content) > 500_000 and bundle.headers["content-type"].startswith(
        ("application/javascript", "text/javascript")
    )
    version = re.search(rb'"(5\.\d+\.\d+)"', bundle.content)
    assert version is not None, "Swagger UI 5 (OpenAPI 3.1) expected"
    assert client.get("/v1/openapi.json").json()["openapi"].startswith("3.1")
