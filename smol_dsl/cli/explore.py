"""`smol-dsl explore`: a local web page to watch finished runs' archives through their phases
and see any elite walk."""

from __future__ import annotations

import errno
import logging
import socket
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor, wait
from pathlib import Path
from typing import TYPE_CHECKING

from smol_dsl.cli.common import EXIT_OK, UsageError

if TYPE_CHECKING:
    import argparse

HOST = "127.0.0.1"
DEFAULT_PORT = 8765


def add_parser(commands: argparse._SubParsersAction) -> None:
    explore = commands.add_parser(
        "explore",
        help="a local web page: finished runs' archives through their phases, any elite's gait on a click",
        description="Serve a page on 127.0.0.1 that shows each finished run's archive at the start and end of "
        "every phase (a slider and a play button; the coverage and max-fitness curves below it; another run "
        "beside it at the same moment, on one colour scale), and, for a "
        "clicked cell, the final archive's elite rolled out in the final body and the child's (phase 0), with its "
        "fitness and descriptor "
        "(the same rollout as `render`; cached, so a second click is instant). The view is in the URL. Ctrl-C stops.",
    )
    explore.add_argument("paths", nargs="+", metavar="PATH", help="run or sweep directories (searched recursively)")
    explore.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"the port (default {DEFAULT_PORT}; 0: any free)"
    )
    explore.add_argument("--no-browser", action="store_true", help="print the URL instead of opening a browser")
    explore.add_argument(
        "--cache",
        metavar="DIR",
        help="where rendered gaits are kept (default: smol-dsl-explore in the system's temporary directory)",
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


def explore_runs(args: argparse.Namespace) -> int:
    from werkzeug.serving import make_server

    from smol_dsl.cli.run import use_cpu_cores_as_devices
    from smol_dsl.rescoring.replay import replay_elites
    from smol_dsl.results.explorer import Explorer, create_app

    sock = bound_socket(args.port)  # before reading anything: a busy port is refused at once
    cache = Path(args.cache) if args.cache else Path(tempfile.gettempdir()) / "smol-dsl-explore"
    use_cpu_cores_as_devices()  # as the runs trained: their scoring programs (see `smol-dsl render`)
    try:
        explorer = Explorer(args.paths, replay=replay_elites, cache=cache)
    except BaseException:
        sock.close()
        raise
    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # no line per request
    server = make_server(HOST, sock.getsockname()[1], create_app(explorer), threaded=True, fd=sock.fileno())
    url = f"http://{HOST}:{sock.getsockname()[1]}/"
    stopping = threading.Event()
    report_error = server.handle_error

    def handle_error(request: object, client_address: object) -> None:
        if not stopping.is_set():  # after Ctrl-C, a request cut short is no error
            report_error(request, client_address)

    server.handle_error = handle_error
    print(f"smol-dsl explore: {len(explorer.runs)} run(s) at {url} (Ctrl-C stops)", flush=True)
    for problem in explorer.problems:
        print(f"note: left out: {problem}", file=sys.stderr)
    if not args.no_browser:
        import webbrowser

        webbrowser.open(url)
    # The loop serves in a thread of its own, so Ctrl-C reaches the main thread while it only
    # waits: a KeyboardInterrupt raised inside the loop could close a connection a handler
    # thread had just been given, and that handler would report the closed socket as an error.
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="explore-server") as pool:
        serving = pool.submit(server.serve_forever)
        try:
            while not serving.done():  # waits with a timeout: a wait without one may not see Ctrl-C
                wait([serving], timeout=0.5)
            serving.result()  # the loop ended by itself: it failed, and its error is raised here
        except KeyboardInterrupt:
            stopping.set()
            logging.getLogger("werkzeug").disabled = True  # nor is a render refused by the closing explorer
            server.shutdown()  # the loop ends between two requests and closes the socket
        finally:
            explorer.close()
            sock.close()
    print("smol-dsl explore: stopped", file=sys.stderr)
    return EXIT_OK
