"""`smol-dsl explore`: a local web page to watch finished runs' archives through their phases
and see any elite walk.

The server listens on 127.0.0.1 only and answers only requests that name this machine and
carry the random token of the URL it prints (`smol_dsl.results.explorer_app`). Its work is
bounded: connections (`MOST_CONNECTIONS`, each closed after `IDLE_SECONDS` without a
request), renders (`explorer.MOST_QUEUED`) and the gait cache on disk (`--cache-size`).
"""

from __future__ import annotations

import errno
import logging
import socket
import sys
import threading
from concurrent.futures import ThreadPoolExecutor, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.cli.common import EXIT_OK, UsageError

if TYPE_CHECKING:
    import argparse

HOST = "127.0.0.1"
DEFAULT_PORT = 8765
MOST_CONNECTIONS = 64
"""Connections served at once; one more is answered 503 and closed at once."""
IDLE_SECONDS = 5.0
"""A connection that sends nothing (or stops reading) this long is closed."""
_BUSY = b"too many connections at once; try again shortly"
BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\nConnection: close\r\n"
    b"Content-Length: %d\r\n\r\n%s" % (len(_BUSY), _BUSY)
)


def add_parser(commands: argparse._SubParsersAction) -> None:
    from smol_dsl.results.gait_cache import DEFAULT_CACHE_MB

    explore = commands.add_parser(
        "explore",
        help="a local web page: finished runs' archives through their phases, any elite's gait on a click",
        description="Serve a page on 127.0.0.1 that shows each finished run's archive at the start and end of "
        "every phase (a slider and a play button; the coverage and max-fitness curves below it; another run "
        "beside it at the same moment, on one colour scale), and, for a "
        "clicked cell, the final archive's elite rolled out in the final body and the child's (phase 0), with its "
        "fitness and descriptor "
        "(the same rollout as `render`; cached, so a second click is instant). The view is in the URL. The server "
        "answers only requests to 127.0.0.1 or localhost that carry the random token of the URL it prints "
        "(?token=...; the page keeps it), so other web pages cannot read the runs or start renders. Ctrl-C stops.",
    )
    explore.add_argument("paths", nargs="+", metavar="PATH", help="run or sweep directories (searched recursively)")
    explore.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"the port (default {DEFAULT_PORT}; 0: any free)"
    )
    explore.add_argument("--no-browser", action="store_true", help="print the URL instead of opening a browser")
    explore.add_argument(
        "--cache",
        metavar="DIR",
        help="where rendered gaits are kept: a directory of your own that only you can write (made mode 700; a "
        "symlink is refused). Default: smol-dsl/explore in your cache directory ($XDG_CACHE_HOME or ~/.cache; "
        "~/Library/Caches on macOS)",
    )
    explore.add_argument(
        "--cache-size",
        type=int,
        default=DEFAULT_CACHE_MB,
        metavar="MB",
        help=f"the gait cache's bound in MB: past it, the least recently used gaits are removed (default "
        f"{DEFAULT_CACHE_MB}; a gait of the quick preset is about 150 kB)",
    )
    explore.add_argument(
        "--allow-mixed-environments",
        action="store_true",
        help="show runs simulated on different physics (--physics) together, each labelled with its own; "
        "refused otherwise, since their archives are not comparable side by side",
    )
    explore.set_defaults(handle=explore_runs)


def bound_socket(port: int) -> socket.socket:
    """A socket listening on 127.0.0.1:port; a UsageError for a port in use or not allowed."""
    if not 0 <= port <= 65535:
        raise UsageError(f"--port {port}: a port is a number from 0 to 65535")
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind((HOST, port))
    except OSError as error:
        sock.close()
        if error.errno == errno.EADDRINUSE:
            raise UsageError(
                f"--port {port}: port {port} is in use; give another, or --port 0 for any free one"
            ) from None
        raise UsageError(f"--port {port}: cannot listen on it ({error.strerror or error}); give another") from None
    sock.listen(64)
    return sock


def gait_cache(args: argparse.Namespace) -> Path:
    """The gait cache's directory, made or checked (`private_directory`); a UsageError naming
    --cache for one that is not the user's own, and for a bound below 1 MB."""
    from smol_dsl.results.gait_cache import CacheError, default_cache_directory, private_directory

    if args.cache_size < 1:
        raise UsageError(f"--cache-size {args.cache_size}: give the bound in MB, at least 1")
    path = Path(args.cache) if args.cache else default_cache_directory()
    try:
        return private_directory(path)
    except CacheError as error:
        raise UsageError(f"--cache {path}: {error}" if args.cache else f"the gait cache: {error}") from None


def explore_runs(args: argparse.Namespace) -> int:
    from smol_dsl.cli.run import use_cpu_cores_as_devices
    from smol_dsl.rescoring.replay import replay_elites
    from smol_dsl.results.explorer import Explorer
    from smol_dsl.results.explorer_app import create_app, new_token

    sock = bound_socket(args.port)  # before reading anything: a busy port is refused at once
    try:
        cache = gait_cache(args)
        use_cpu_cores_as_devices()  # as the runs trained: their scoring programs (see `smol-dsl render`)
        explorer = Explorer(
            args.paths,
            replay=replay_elites,
            cache=cache,
            cache_bytes=args.cache_size * 10**6,
            allow_mixed_environments=args.allow_mixed_environments,
        )
    except BaseException:
        sock.close()
        raise
    explorer.cache.evict()  # a bound lowered since the last session holds from the start
    port, token = sock.getsockname()[1], new_token()
    server = bounded_server(port, create_app(explorer, token, port), sock)
    url = f"http://{HOST}:{port}/?token={token}"
    stopping = threading.Event()
    report_error = server.handle_error

    def handle_error(request: object, client_address: object) -> None:
        if not stopping.is_set():  # after Ctrl-C, a request cut short is no error
            report_error(request, client_address)

    server.handle_error = handle_error  # type: ignore[method-assign]
    # The loop serves in a thread of its own, so Ctrl-C reaches the main thread while it only
    # waits: a KeyboardInterrupt raised inside the loop could close a connection a handler
    # thread had just been given, and that handler would report the closed socket as an error.
    # It is started before the URL is printed, so a Ctrl-C from then on finds it to stop.
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="explore-server") as pool:
        try:
            serving = pool.submit(server.serve_forever)
            print(f"smol-dsl explore: {len(explorer.runs)} run(s) at {url} (Ctrl-C stops)", flush=True)
            print(f"note: gaits are kept in {cache} (at most {args.cache_size} MB)", file=sys.stderr)
            for problem in explorer.problems:
                print(f"note: left out: {problem}", file=sys.stderr)
            if not args.no_browser:
                import webbrowser

                webbrowser.open(url)
            while not serving.done():  # waits with a timeout: a wait without one may not see Ctrl-C
                wait([serving], timeout=0.5)
            serving.result()  # the loop ended by itself: it failed, and its error is raised here
        except KeyboardInterrupt:
            stopping.set()
            logging.getLogger("werkzeug").disabled = True  # nor is a render refused by the closing explorer
            server.shutdown()  # the loop ends between two requests (or at once) and closes the socket
        finally:
            explorer.close()
            sock.close()
    print("smol-dsl explore: stopped", file=sys.stderr)
    return EXIT_OK


def bounded_server(port: int, app: Any, sock: socket.socket) -> Any:
    """werkzeug's threaded server on `sock`, at most MOST_CONNECTIONS connections at once
    (one more is answered 503 and closed), each closed after IDLE_SECONDS idle; its log
    (a malformed request's line) goes to stderr once, not also through the root logger that
    a library may have set up."""
    from werkzeug.serving import ThreadedWSGIServer, WSGIRequestHandler

    log = logging.getLogger("werkzeug")
    log.setLevel(logging.ERROR)  # no line per request
    log.propagate = False
    if not log.handlers:
        log.addHandler(logging.StreamHandler(sys.stderr))

    class Handler(WSGIRequestHandler):
        timeout = IDLE_SECONDS  # every read and write of the connection

        def log_error(self, format: str, *args: Any) -> None:
            if not format.startswith("Request timed out"):  # an idle connection closed: no error
                super().log_error(format, *args)

    class Server(ThreadedWSGIServer):
        slots = threading.BoundedSemaphore(MOST_CONNECTIONS)

        def process_request(self, request: Any, client_address: Any) -> None:
            if not self.slots.acquire(blocking=False):
                try:
                    request.settimeout(1.0)
                    request.sendall(BUSY)
                except OSError:
                    pass
                self.shutdown_request(request)
                return
            try:
                super().process_request(request, client_address)
            except BaseException:
                self.slots.release()
                raise

        def process_request_thread(self, request: Any, client_address: Any) -> None:
            try:
                super().process_request_thread(request, client_address)
            finally:
                self.slots.release()

    return Server(HOST, port, app, handler=Handler, fd=sock.fileno())
