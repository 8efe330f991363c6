"""The annotation web server (Flask, served by waitress).

HTTP API (all JSON responses; errors are ``{"error": message}`` with a 4xx status)
--------------------------------------------------------------------------------
``GET /``
    The annotator page (``static/index.html``); ``/static/<file>`` its JS/CSS.
``GET /api/info``
    ``recording``, ``n_frames``, ``width``, ``height``, ``start_ns`` (of frame 0),
    ``color_format``, ``max_operator_len``.
``GET /api/frames/<i>/color``
    Colour image of frame ``i`` (JPEG or PNG).
``GET /api/frames/<i>/depth``
    Colour-mapped depth of frame ``i`` (PNG with alpha); 404 when it has none.
``GET /api/frames/<i>/meta``
    ``frame``, ``timestamp_ns``, ``width``, ``height``, ``has_depth``.
``GET /api/operators/<name>/clicks``
    The operator's own clicks: ``operator``, ``n_frames``, ``done``, ``clicks`` (list).
``GET /api/frames/<i>/clicks?operator=NAME``
    ``own`` (the operator's click or null) and, only once the operator has done
    the frame, ``others`` (the other operators' clicks) and ``reference``
    (mean and spread of all clicks, see :func:`~fusion_pf.annotate.db.summarize_frame`);
    before that ``others`` and ``reference`` are null and ``hidden`` is true
    (independent annotation).
``POST /api/clicks``
    JSON body ``{"operator": str, "frame": int, "u": float, "v": float}``, or
    ``u`` and ``v`` null for "not visible". Stores (replaces) the click, commits,
    then answers like ``GET /api/frames/<i>/clicks`` plus ``done``.

Bad input (unknown path, frame out of range, click outside the image, malformed
or non-object JSON, wrong content type, a body over :data:`MAX_BODY_BYTES`)
gets a 4xx JSON error and writes nothing.

DNS rebinding and cross-site writes
-----------------------------------
Every request must name this server in its ``Host`` header: ``localhost``, an
IP address, or the bound host name (plus the machine's names when bound to
all interfaces), with the bound port; anything else (``Host: evil.example``, a
name an attacker's DNS points at 127.0.0.1) gets 421 and no data. Writes
(``POST``) carrying an ``Origin`` header other than this server's own, or
``Sec-Fetch-Site: cross-site``, get 403.

Connections
-----------
Any local process can open connections, so none may lock operators out or
crash the server (:mod:`.connections`): waitress waits with ``poll()``
(``select()`` dies on a descriptor >= 1024); a client address keeps at most
``max_connections_per_client`` connections and the server ``max_connections``:
a new connection beyond either closes the oldest idle one (of that address,
or of the address holding the most), so a new one is always let in while any
is idle. A connection must hand in a complete request within ``idle_timeout``
of opening or of its previous request, however slowly it trickles bytes.
:func:`serve` raises the soft descriptor limit toward the hard one so the
connections fit; out of descriptors, the server closes an idle connection or
pauses accepting, and never stops.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import socket
from collections.abc import Callable
from pathlib import Path
from urllib.parse import urlsplit

from flask import Flask, Response, jsonify, request, send_from_directory
from flask.json.provider import DefaultJSONProvider
from werkzeug.exceptions import HTTPException

from fusion_pf.errors import InputError, RecordingError

from .db import MAX_OPERATOR_LEN, AnnotationDB, summarize_frame, validate_operator
from .frames import FrameImages
from .options import ServeOptions

#: Largest request body accepted, in bytes (a click is ~100 bytes).
MAX_BODY_BYTES = 4096

#: Config key of the ``(host names, port)`` the Host header may name (set by :func:`serve`).
HOSTS_KEY = "FUSION_PF_HOSTS"

#: Folder of the page's HTML, JS and CSS.
STATIC_DIR = Path(__file__).with_name("static")

_log = logging.getLogger(__name__)


class ApiError(Exception):
    """An error answered with ``status`` and ``{"error": message}``."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


def _frame_view(db: AnnotationDB, frame: int, operator: str) -> dict:
    clicks = db.frame_clicks(frame)
    own = next((c for c in clicks if c.operator == operator), None)
    view: dict[str, object] = {
        "frame": frame,
        "own": own.to_json() if own else None,
        "hidden": own is None,
        "others": None,
        "reference": None,
    }
    if own is not None:
        view["others"] = [c.to_json() for c in clicks if c.operator != operator]
        view["reference"] = summarize_frame(clicks)
    return view


def _operator_arg() -> str:
    name = request.args.get("operator")
    if name is None:
        raise ApiError(400, "query parameter 'operator' is required")
    return validate_operator(name)


def _json_body() -> dict:
    if request.mimetype != "application/json":
        raise ApiError(415, f"body must be application/json, got {request.mimetype or 'nothing'!r}")
    raw = request.get_data(cache=False)
    if len(raw) > MAX_BODY_BYTES:
        raise ApiError(413, f"body must be at most {MAX_BODY_BYTES} bytes, got {len(raw)}")
    try:
        body = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ApiError(400, f"body is not valid JSON: {exc}") from None
    except RecursionError:
        raise ApiError(400, "body is not valid JSON: nested too deeply") from None
    except ValueError as exc:  # e.g. an integer beyond sys.get_int_max_str_digits()
        raise ApiError(400, f"body is not valid JSON: {exc}") from None
    if not isinstance(body, dict):
        raise ApiError(400, f"body must be a JSON object, got {type(body).__name__}")
    return body


def _split_host(text: str) -> tuple[str, int | None] | None:
    """``(lower-case host name, port or None)`` of a Host header value or origin netloc; None if malformed."""
    try:
        parts = urlsplit("//" + text)
        return (parts.hostname or "", parts.port) if parts.hostname else None
    except ValueError:
        return None


def host_allowed(host_header: str | None, names: frozenset[str], port: int | None) -> bool:
    """Whether a ``Host`` header names this server (see the module notes on DNS rebinding).

    Parameters
    ----------
    host_header : str or None
        The request's Host header.
    names : frozenset of str
        Host names accepted besides ``localhost`` and IP literals (lower case).
    port : int or None
        The bound port; None accepts any.
    """
    split = _split_host(host_header or "")
    if split is None:
        return False
    name, given = split
    if port is not None and (given or 80) != port:
        return False
    if name == "localhost" or name in names:
        return True
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True  # an IP address cannot be rebound to another host


def _reject_constant(name: str) -> float:
    raise ApiError(400, f"body is not valid JSON: {name} is not a number in JSON")


def create_app(images: FrameImages, db: AnnotationDB, *, recording: str) -> Flask:
    """Build the Flask application serving ``images`` and storing clicks in ``db``.

    Parameters
    ----------
    images : FrameImages
        The recording's frames.
    db : AnnotationDB
        The click database (same frame count and size as ``images``).
    recording : str
        Name shown in the page.

    Returns
    -------
    Flask
        The WSGI application (serve it with :func:`serve`).
    """
    if db.n_frames != images.n_frames:
        raise InputError(f"database has {db.n_frames} frames, recording has {images.n_frames}")
    app = Flask(__name__, static_folder=str(STATIC_DIR), static_url_path="/static")
    app.config["MAX_CONTENT_LENGTH"] = MAX_BODY_BYTES
    app.url_map.merge_slashes = False  # no HTML redirects: '//x' is just an unknown path
    assert isinstance(app.json, DefaultJSONProvider)  # Flask's default provider: it has sort_keys
    app.json.sort_keys = False
    first = images.meta(0)

    @app.before_request
    def _same_site() -> None:
        names, port = app.config.get(HOSTS_KEY, (frozenset(), None))
        if not host_allowed(request.host, names, port):
            raise ApiError(
                421, f"Host {request.host[:80]!r} is not this server; open it as http://localhost:{port or '<port>'}/"
            )
        if request.method not in ("GET", "HEAD", "OPTIONS"):
            origin = request.headers.get("Origin")
            if origin is not None:
                parts = urlsplit(origin) if origin != "null" else None
                if parts is None or parts.scheme != "http" or parts.netloc.lower() != request.host.lower():
                    raise ApiError(403, f"cross-origin write refused (Origin {origin[:80]!r})")
            if request.headers.get("Sec-Fetch-Site") == "cross-site":
                raise ApiError(403, "cross-site write refused")

    @app.errorhandler(ApiError)
    def _api_error(exc: ApiError) -> tuple[Response, int]:
        return jsonify(error=exc.message), exc.status

    @app.errorhandler(InputError)
    def _input_error(exc: InputError) -> tuple[Response, int]:
        return jsonify(error=str(exc)), 400

    @app.errorhandler(RecordingError)
    def _recording_error(exc: RecordingError) -> tuple[Response, int]:
        _log.error("recording error on %s: %s", request.path, exc)
        return jsonify(error=f"the recording cannot be read here: {exc}"), 500

    @app.errorhandler(HTTPException)
    def _http_error(exc: HTTPException) -> tuple[Response, int]:
        status = exc.code or 500
        if status == 413:
            message = f"body must be at most {MAX_BODY_BYTES} bytes"
        else:
            message = f"{exc.name}: {exc.description}"
        return jsonify(error=message), status

    @app.errorhandler(Exception)
    def _unexpected(exc: Exception) -> tuple[Response, int]:
        _log.exception("unexpected error on %s %s", request.method, request.path)
        return jsonify(error=f"internal error: {type(exc).__name__}"), 500

    @app.after_request
    def _headers(resp: Response) -> Response:
        resp.headers.setdefault("X-Content-Type-Options", "nosniff")
        resp.headers.setdefault("Referrer-Policy", "no-referrer")
        if resp.mimetype == "text/html":
            resp.headers["Content-Security-Policy"] = (
                "default-src 'self'; img-src 'self' blob:; object-src 'none'; base-uri 'none'; frame-ancestors 'none'"
            )
        if request.path.startswith("/api/") and not request.path.endswith(("/color", "/depth")):
            resp.headers["Cache-Control"] = "no-store"
        return resp

    @app.get("/")
    def index() -> Response:
        return send_from_directory(STATIC_DIR, "index.html", max_age=0)

    @app.get("/favicon.ico")
    def favicon() -> Response:
        return Response(status=204)

    @app.get("/api/info")
    def info() -> Response:
        return jsonify(
            recording=recording,
            n_frames=images.n_frames,
            width=first.width,
            height=first.height,
            start_ns=first.timestamp_ns,
            color_format=images.color_format,
            max_operator_len=MAX_OPERATOR_LEN,
        )

    @app.get("/api/frames/<int:index>/meta")
    def frame_meta(index: int) -> Response:
        m = images.meta(_frame_index(index))
        return jsonify(
            frame=m.index, timestamp_ns=m.timestamp_ns, width=m.width, height=m.height, has_depth=m.has_depth
        )

    @app.get("/api/frames/<int:index>/color")
    def frame_color(index: int) -> Response:
        data = images.color(_frame_index(index))
        resp = Response(data, mimetype=images.color_mimetype)
        resp.headers["Cache-Control"] = "private, max-age=3600"
        return resp

    @app.get("/api/frames/<int:index>/depth")
    def frame_depth(index: int) -> Response:
        data = images.depth(_frame_index(index))
        if data is None:
            raise ApiError(404, f"frame {index} has no depth image")
        resp = Response(data, mimetype="image/png")
        resp.headers["Cache-Control"] = "private, max-age=3600"
        return resp

    @app.get("/api/frames/<int:index>/clicks")
    def frame_clicks(index: int) -> Response:
        return jsonify(_frame_view(db, _frame_index(index), _operator_arg()))

    @app.get("/api/operators/<path:name>/clicks")
    def operator_clicks(name: str) -> Response:
        operator = validate_operator(name)
        clicks = db.operator_clicks(operator)
        return jsonify(
            operator=operator, n_frames=images.n_frames, done=len(clicks), clicks=[c.to_json() for c in clicks]
        )

    @app.post("/api/clicks")
    def post_click() -> Response:
        body = _json_body()
        unknown = sorted(set(body) - {"operator", "frame", "u", "v"})
        if unknown:
            raise ApiError(400, f"unknown keys {unknown}; expected operator, frame, u, v")
        missing = sorted({"operator", "frame", "u", "v"} - set(body))
        if missing:
            raise ApiError(400, f"missing keys {missing} (u and v are null for 'not visible')")
        operator = validate_operator(body["operator"])
        frame, u, v = db.check_click(body["frame"], body["u"], body["v"])
        meta = images.meta(frame)
        if u is not None and v is not None and not (u <= meta.width - 0.5 and v <= meta.height - 0.5):
            raise ApiError(400, f"({u}, {v}) is outside the {meta.width}x{meta.height} image of frame {frame}")
        db.set_click(operator, frame, meta.timestamp_ns, u, v)
        view = _frame_view(db, frame, operator)
        view["done"] = db.count_clicks(operator)
        return jsonify(view)

    def _frame_index(index: int) -> int:
        if not 0 <= index < images.n_frames:
            raise ApiError(404, f"frame {index} is out of range [0, {images.n_frames})")
        return index

    return app


def serve(app: Flask, opts: ServeOptions | None = None, *, on_ready: Callable[[str], None] | None = None) -> None:
    """Serve ``app`` with waitress, guarded against connection floods (:mod:`.connections`), until interrupted.

    Parameters
    ----------
    app : Flask
        From :func:`create_app`.
    opts : ServeOptions, optional
        Interface, port, worker threads and connection caps (defaults: ``ServeOptions()``, bound to 127.0.0.1).
    on_ready : callable, optional
        Called with the URL once the socket is bound, before serving.
    """
    from .connections import create_server

    opts = opts or ServeOptions()
    server = create_server(app, opts)
    bound_host = server.effective_host
    names = {opts.host.lower().strip("[]")}
    try:
        wildcard = ipaddress.ip_address(opts.host.strip("[]")).is_unspecified
    except ValueError:
        wildcard = False
    if wildcard:
        names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
    app.config[HOSTS_KEY] = (frozenset(names), int(server.effective_port))
    url = f"http://{'[' + bound_host + ']' if ':' in bound_host else bound_host}:{server.effective_port}/"
    if on_ready is not None:
        on_ready(url)
    try:
        server.run()
    finally:
        server.close()
