"""What stands between the network and the studio: Host, Origin and cross-site checks, the page's
content security policy, request bodies read with a size limit and a timeout, strict JSON,
query strings, and a deadline for each request's headers (a trickling client is cut off).
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import re

try:  # the "web" extra
    from starlette.requests import ClientDisconnect
    from starlette.responses import JSONResponse
except ImportError:  # pragma: no cover - reported by run_cli / create_app
    ClientDisconnect = JSONResponse = None

MAX_BODY = 64 * 1024          # bytes of a request body
BODY_TIMEOUT = 10.0           # seconds to receive a request body
HEADER_TIMEOUT = 10.0         # seconds to receive a request's headers
KEEP_ALIVE_TIMEOUT = 5        # seconds an idle keep-alive connection stays open
MAX_HEADER_BYTES = 16 * 1024  # request headers (431 beyond)


class ApiError(Exception):
    """A request the server refuses: HTTP status, message and the field at fault (if any)."""

    def __init__(self, status: int, message: str, field: str | None = None):
        super().__init__(message)
        self.status, self.message, self.field = status, message, field


def query_params(query) -> dict:
    """Request fields from a query string (numbers and booleans parsed from text)."""
    raw = {}
    for k, v in query.multi_items():
        if k in raw:
            raise ApiError(422, f"{k[:40]}: given more than once", k[:40])
        if k in ("a_end", "b_start", "length", "key_at"):
            if not re.fullmatch(r"[+-]?\d{1,12}", v.strip()):
                raise ApiError(422, f"{k}: must be a whole number, got {v[:40]!r}", k)
            raw[k] = int(v)
        elif k == "alpha":
            try:
                raw[k] = float(v)
            except ValueError:
                raise ApiError(422, f"alpha: must be a number between 0 and 1, got {v[:40]!r}", k) from None
        elif k in ("align", "foot_lock"):
            if v.lower() not in ("true", "false", "1", "0"):
                raise ApiError(422, f"{k}: must be true or false, got {v[:40]!r}", k)
            raw[k] = v.lower() in ("true", "1")
        else:
            raw[k] = v
    return raw


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def _unique_keys(pairs: list) -> dict:
    """A JSON object's members as a dict, refusing a name given twice (which one would win is
    left open by RFC 8259; a client that sends both meant something it will not get)."""
    out = dict(pairs)
    if len(out) != len(pairs):
        seen = set()
        name = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise ValueError(f"member {name[:40]!r} given twice")
    return out


class Disconnected(Exception):
    """The client went away before its request was read (answered quietly: nobody listens)."""


def _is_json(content_type: str) -> bool:
    return content_type.split(";", 1)[0].strip().lower() == "application/json"


_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")  # a JSON escape of a UTF-16 surrogate (D800-DFFF)


async def read_json(request) -> object:
    """The request body as JSON.

    415 unless ``Content-Type: application/json`` (a cross-site form cannot send that without
    the browser asking first), 413 over :data:`MAX_BODY` bytes, 408 when the body takes longer
    than :data:`BODY_TIMEOUT` seconds, 400 when not valid JSON in UTF-8 (RFC 8259; a byte order
    mark is skipped, no other encoding is guessed, a lone surrogate escaped as ``\\ud800`` is
    refused: no error message could hold it) or when an object names a member twice;
    :class:`Disconnected` when the client leaves.
    """
    if not _is_json(request.headers.get("content-type", "")):
        raise ApiError(415, "send the body as JSON with 'Content-Type: application/json'")
    try:
        async with asyncio.timeout(BODY_TIMEOUT):
            body = await _read_body(request)
    except TimeoutError:
        raise ApiError(408, f"request body not received within {BODY_TIMEOUT:g} s") from None
    except ClientDisconnect:
        raise Disconnected from None
    if not body.strip():
        raise ApiError(400, "empty body: send a JSON object")
    try:
        text = bytes(body).decode("utf-8-sig")
        value = json.loads(text, parse_constant=_reject_constant, object_pairs_hook=_unique_keys)
        if _SURROGATE_ESCAPE.search(text):  # UTF-8 holds no surrogate: only an escape can make one
            json.dumps(value, ensure_ascii=False).encode("utf-8")  # a lone one (D800) is no text
        return value
    except RecursionError:
        raise ApiError(400, "body is not valid JSON (nested too deeply)") from None
    except (ValueError, UnicodeDecodeError) as e:
        raise ApiError(400, f"body is not valid JSON ({str(e)[:120]})") from None


async def _read_body(request) -> bytearray:
    """The body, at most :data:`MAX_BODY` bytes (413 beyond, from the header or while streaming)."""
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.strip().isdigit():
            raise ApiError(400, "bad Content-Length header")
        if int(declared) > MAX_BODY:
            raise ApiError(413, f"request body too large ({int(declared)} bytes; at most {MAX_BODY})")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY:
            raise ApiError(413, f"request body too large (at most {MAX_BODY} bytes)")
    return body


# -- the guard ------------------------------------------------------------------------------
def page_policy(index) -> str:
    """Content-Security-Policy of the page ``index`` (a Path): own files only, plus the page's
    inline import map."""
    hashes = ""
    if index.is_file():
        for block in re.findall(r'<script type="importmap">(.*?)</script>', index.read_text("utf-8"), re.DOTALL):
            digest = base64.b64encode(hashlib.sha256(block.encode("utf-8")).digest()).decode()
            hashes += f" 'sha256-{digest}'"
    return ("default-src 'self'; script-src 'self'" + hashes + "; style-src 'self'; "
            "img-src 'self' data: blob:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
            "form-action 'none'; frame-ancestors 'none'")


def cross_site(headers: dict, path: str) -> str | None:
    """Why a request must be refused as cross-site, or None (see the module docstring).

    ``headers`` maps lower-case header names to values (bytes). A browser sends ``Origin``
    on every POST and on cross-origin fetches; it must be this server's own origin
    (``http://`` or ``https://`` plus the ``Host`` header). ``Sec-Fetch-Site`` covers requests
    without ``Origin`` (an ``<img>`` or ``<script>`` pointing at ``/api/export``): other sites
    may link to the page, not use the API.
    """
    origin = headers.get(b"origin")
    if origin is not None:
        host = headers.get(b"host", b"").decode("latin-1").lower()
        if origin.decode("latin-1").lower() not in (f"http://{host}", f"https://{host}"):
            return f"cross-origin request from {origin.decode('latin-1')[:80]!r} refused"
    site = headers.get(b"sec-fetch-site", b"").lower()
    if path.startswith("/api/") and site in (b"cross-site", b"same-site"):
        return f"cross-site request ({site.decode('latin-1')}) to the API refused"
    return None


class Guard:
    """ASGI middleware: refuses foreign Host headers (DNS rebinding) and cross-site requests
    (:func:`cross_site`), and adds security headers."""

    def __init__(self, app, allowed_hosts=None, policy: str = "default-src 'self'"):
        self.app = app
        self.allowed = None if allowed_hosts is None else {h.lower() for h in allowed_hosts}
        self.headers = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"),
                        (b"x-frame-options", b"DENY"),
                        (b"content-security-policy", policy.encode())]

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        if sum(len(k) + len(v) + 4 for k, v in scope["headers"]) > MAX_HEADER_BYTES:
            resp = JSONResponse({"error": f"request headers larger than {MAX_HEADER_BYTES} bytes", "field": None}, 431)
            return await resp(scope, receive, send)
        headers = dict(scope["headers"])
        refused = cross_site(headers, scope.get("path", ""))
        if refused:
            return await JSONResponse({"error": refused, "field": None}, 403)(scope, receive, send)
        if self.allowed is not None:
            host = headers.get(b"host", b"").decode("latin-1").lower()
            name = host[1:].split("]")[0] if host.startswith("[") else host.rsplit(":", 1)[0]
            if name not in self.allowed:
                resp = JSONResponse({"error": f"unexpected Host header {host[:80]!r}", "field": None}, 400)
                return await resp(scope, receive, send)
        extra = self.headers

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                message = dict(message)
                message["headers"] = list(message.get("headers", [])) + extra
            await send(message)

        return await self.app(scope, receive, send_with_headers)


def timed_h11():
    """uvicorn's h11 protocol with a deadline for each request's headers (a trickling client is cut off)."""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class TimedH11Protocol(H11Protocol):
        _header_timer = None

        def connection_made(self, transport):
            super().connection_made(transport)
            self._arm()

        def _arm(self):
            if self._header_timer is None:
                self._header_timer = self.loop.call_later(HEADER_TIMEOUT, self._headers_too_slow)

        def _disarm(self):
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _headers_too_slow(self):
            self._header_timer = None
            if not self.transport.is_closing():
                self.transport.close()

        def data_received(self, data: bytes) -> None:
            cycle = self.cycle
            if cycle is None or cycle.response_complete:
                self._arm()  # bytes of a new request: its headers must come in time
            super().data_received(data)
            if self.cycle is not cycle:  # a request's headers were parsed
                self._disarm()

        def connection_lost(self, exc):
            self._disarm()
            super().connection_lost(exc)

    return TimedH11Protocol


