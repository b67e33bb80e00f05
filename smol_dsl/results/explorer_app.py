"""The explorer's web app: the page, the runs' data and the cached gaits, to this machine's
browser only.

A local server is reachable by any web page the user opens, through the browser: a page of
another site can send requests to 127.0.0.1 (a cross-site `<img>` or form), or, through DNS
rebinding, read the answers under a name of its own that resolves to 127.0.0.1. So, as
Jupyter does, every request must name this machine in its Host header (127.0.0.1,
localhost or [::1], with or without the port), and everything that reads data or starts work
(`/api/...` and `/gaits/...`) must carry the random token the command printed in its URL: the
page's fetches send it in a header, its `<img>` in the query. Answers forbid framing, MIME
sniffing and referrers, and the page's policy (CSP) lets only its own inline script run and
only this server be fetched. Nothing else is served: no static files.
"""

from __future__ import annotations

import re
import secrets
from typing import TYPE_CHECKING, Any

from smol_dsl.results.explorer import RequestError
from smol_dsl.results.explorer_page import SCRIPT_HASH, explorer_page
from smol_dsl.results.gaits import RenderError

if TYPE_CHECKING:
    from flask import Flask

    from smol_dsl.results.explorer import Explorer

TOKEN_HEADER = "X-Smol-Dsl-Token"
TOKEN_QUERY = "token"
LOCAL_HOSTS = ("127.0.0.1", "localhost", "[::1]")
SECURITY_HEADERS = {
    "Referrer-Policy": "no-referrer",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Cross-Origin-Resource-Policy": "same-origin",
    "Content-Security-Policy": (
        f"default-src 'none'; script-src '{SCRIPT_HASH}'; style-src 'unsafe-inline'; img-src 'self' data:; "
        "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
}


def new_token() -> str:
    """A random token for the URL (`secrets.token_urlsafe`: 256 bits)."""
    return secrets.token_urlsafe(32)


def local_host(host: str | None, port: int | None) -> bool:
    """Whether a Host header names this machine: 127.0.0.1, localhost or [::1], with no port
    or `port` (any port where `port` is None)."""
    if not host:
        return False
    match = re.fullmatch(r"(127\.0\.0\.1|localhost|\[::1\])(?::([0-9]{1,5}))?", host.lower())
    if match is None:
        return False
    return match.group(2) is None or port is None or int(match.group(2)) == port


def create_app(explorer: Explorer, token: str, port: int | None = None) -> Flask:
    """The Flask app that serves the page, the runs' data and the cached gaits, and nothing
    else: a request naming another host is a 403, an API or gait request without `token` a
    403, every other path a 404, a malformed request a 400 with its reason as JSON."""
    from flask import Flask, Response, jsonify, request

    app = Flask(__name__, static_folder=None)  # no static route: nothing of the working directory is served
    app.json.sort_keys = False  # type: ignore[attr-defined]
    expected = token.encode()

    @app.before_request
    def guard() -> Any:
        given = request.headers.get(TOKEN_HEADER) or request.args.get(TOKEN_QUERY) or ""
        why = refusal(request.headers.get("Host"), request.path, given, port, expected)
        return None if why is None else (jsonify({"error": why}), 403)

    @app.after_request
    def secured(response: Response) -> Response:
        response.headers.update(SECURITY_HEADERS)
        response.headers.setdefault("Cache-Control", "no-store")
        return response

    @app.get("/")
    def page() -> Any:
        return explorer_page(), 200, {"Content-Type": "text/html; charset=utf-8"}

    @app.get("/api/runs")
    def runs() -> Any:
        return jsonify(explorer.run_list())

    @app.get("/api/runs/<number>")
    def run(number: str) -> Any:
        return jsonify(explorer.run_data(number))

    @app.get("/api/runs/<number>/gait")
    def gait(number: str) -> Any:
        return jsonify(explorer.gait(number, request.args.get("cell", ""), request.args.getlist("body")))

    @app.get("/gaits/<name>")
    def gait_image(name: str) -> Any:
        image = explorer.gait_image(name)
        return Response(image, mimetype="image/gif", headers={"Cache-Control": "private, max-age=3600"})

    _answer_errors(app)
    return app


def refusal(host: str | None, path: str, given: str, port: int | None, token: bytes) -> str | None:
    """Why a request is refused (403): a Host that is not this machine, or, but for the page
    itself (which holds no data), a token that is not `token`; None: answer it."""
    if not local_host(host, port):
        return "this server answers requests to 127.0.0.1 or localhost only"
    if path != "/" and not secrets.compare_digest(given.encode("utf-8", "replace"), token):
        return "no token or a wrong one: open the URL `smol-dsl explore` printed (it ends in ?token=...)"
    return None


def _answer_errors(app: Flask) -> None:
    """Every error as JSON with its reason: a refused request's status, a render that cannot
    be done 503, a bug 500 (never a traceback to the browser, never a stopped server)."""
    from flask import jsonify
    from werkzeug.exceptions import HTTPException

    @app.errorhandler(RequestError)
    def refused(error: RequestError) -> Any:
        return jsonify({"error": str(error)}), error.status

    @app.errorhandler(HTTPException)
    def http_error(error: HTTPException) -> Any:
        return jsonify({"error": error.description}), error.code

    @app.errorhandler(RenderError)
    def render_error(error: RenderError) -> Any:
        return jsonify({"error": str(error)}), 503

    @app.errorhandler(Exception)
    def internal(error: Exception) -> Any:
        return jsonify({"error": f"internal error: {type(error).__name__}: {error}"}), 500
