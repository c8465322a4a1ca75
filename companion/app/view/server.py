"""The view's web server (aiohttp): the page, the scene, and frames over a websocket.

Routes: `/` the page and `/static/*` its assets (package data, nothing from the network);
`/api/scene` the static map; `/api/status` the listener's counters; `/ws` a websocket that sends
every frame made so far and then, live, each new one. Query `?algorithm=A&run=R` picks the run
of a replay directory. A client that stalls or leaves is dropped without touching the others or
the mesh listener.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import socket
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Protocol

import msgspec
from aiohttp import WSCloseCode, web

from companion.app.view.live import ListenerStatus, MeshListener
from companion.app.view.replay import Replay, ReplayError, load_replay
from companion.app.view.scene import Scene, build_scene
from companion.contracts.keys import SwarmKeys
from companion.core.world import World

STATIC = Path(str(resources.files("companion.app.view") / "static"))
PUSH_S = 0.2  # how often live clients get the new frames
CHUNK = 1000  # frames per websocket message
SEND_TIMEOUT_S = 10.0  # a client that takes longer to accept a message is dropped


class ReplayStatus(msgspec.Struct, frozen=True):
    """A replay's status (/api/status): always connected, to its directory."""

    connected: bool
    replay: str


class Source(Protocol):
    """Where the frames come from: a live mesh or a replay directory."""

    live: bool

    def scene(self, query: dict[str, str]) -> Scene:
        """The static map of the run the query names."""
        ...

    def frames_since(self, query: dict[str, str], n: int) -> tuple[int, list[str]]:
        """The frames made so far and those from the n-th on."""
        ...

    def status(self) -> ListenerStatus | ReplayStatus:
        """The source's counters (/api/status)."""
        ...

    def close(self) -> None:
        """Release what the source holds."""
        ...


class LiveSource:
    """The mission's mesh, through a read-only `MeshListener`."""

    live = True

    def __init__(self, world: World, seed: int, keys: SwarmKeys | None = None) -> None:
        self.listener = MeshListener(world, keys)
        self._scene = build_scene(world, "live", seed)

    def scene(self, query: dict[str, str]) -> Scene:
        """The mission's static map (the same for every query)."""
        return self._scene

    def frames_since(self, query: dict[str, str], n: int) -> tuple[int, list[str]]:
        """The listener's frames from the n-th on."""
        return self.listener.frames_since(n)

    def status(self) -> ListenerStatus:
        """The listener's counters."""
        return self.listener.status()

    def close(self) -> None:
        """End the listener's session and threads."""
        self.listener.close()


class ReplaySource:
    """A run's output directory; each (algorithm, run) is loaded once, on first request."""

    live = False

    def __init__(
        self,
        directory: Path,
        mission: Path | None = None,
        algorithm: str | None = None,
        run: int | None = None,
    ) -> None:
        self.directory, self.mission = directory, mission
        self.default = (algorithm, run)
        self._cache: dict[tuple[str | None, int | None], Replay] = {}
        self.replay({})  # fail now on a directory (or run) that cannot be replayed

    def replay(self, query: dict[str, str]) -> Replay:
        """The run the query names (`algorithm`, `run`), else the default one."""
        if not query.get("algorithm") and not query.get("run"):
            algorithm, run = self.default
        else:
            algorithm = query.get("algorithm") or None
            try:
                run = int(query["run"]) if query.get("run") else 0
            except ValueError:
                raise ReplayError(f"run {query['run']!r} is not a number") from None
        key = (algorithm, run)
        if key not in self._cache:
            if len(self._cache) >= 8:
                self._cache.clear()
            self._cache[key] = load_replay(self.directory, self.mission, algorithm, run)
        return self._cache[key]

    def scene(self, query: dict[str, str]) -> Scene:
        """The static map of the run the query names."""
        return self.replay(query).scene

    def frames_since(self, query: dict[str, str], n: int) -> tuple[int, list[str]]:
        """All the run's frames, and those from the n-th on."""
        frames = self.replay(query).frames
        return len(frames), frames[n:]

    def status(self) -> ReplayStatus:
        """Connected, to the directory replayed."""
        return ReplayStatus(connected=True, replay=str(self.directory))

    def close(self) -> None:
        """Nothing to release: the replays are in memory."""


def _query(request: web.Request) -> dict[str, str]:
    return {k: request.query[k] for k in ("algorithm", "run") if k in request.query}


async def _index(_request: web.Request) -> web.FileResponse:
    return web.FileResponse(STATIC / "index.html")


async def _scene(request: web.Request) -> web.Response:
    try:
        scene = await asyncio.to_thread(request.app["source"].scene, _query(request))
    except ReplayError as exc:
        return web.json_response({"error": str(exc)}, status=404)
    return web.json_response(msgspec.to_builtins(scene))


async def _status(request: web.Request) -> web.Response:
    """The source's counters and the number of pages connected."""
    status = msgspec.to_builtins(request.app["source"].status())
    return web.json_response({**status, "pages": len(request.app["sockets"])})


async def _push(ws: web.WebSocketResponse, source: Source, query: dict[str, str]) -> None:
    """Send the frames (all so far, then new ones when live) and the status, until the end."""
    sent = 0
    while not ws.closed:
        try:
            made, frames = await asyncio.to_thread(source.frames_since, query, sent)
        except ReplayError as exc:
            await ws.send_str(json.dumps({"type": "error", "error": str(exc)}))
            await ws.close()
            return
        for i in range(0, len(frames), CHUNK):
            text = '{"type":"frames","frames":[' + ",".join(frames[i : i + CHUNK]) + "]}"
            await asyncio.wait_for(ws.send_str(text), SEND_TIMEOUT_S)
        sent = made
        status = {"type": "status", "live": source.live, **msgspec.to_builtins(source.status())}
        await asyncio.wait_for(ws.send_str(json.dumps(status)), SEND_TIMEOUT_S)
        if not source.live:
            return
        await asyncio.sleep(PUSH_S)


async def _websocket(request: web.Request) -> web.WebSocketResponse:
    ws = web.WebSocketResponse(heartbeat=20.0)
    await ws.prepare(request)
    request.app["sockets"].add(ws)
    pusher = asyncio.create_task(_push(ws, request.app["source"], _query(request)))
    try:
        async for _msg in ws:  # the page sends nothing; this notices when it leaves
            pass
    finally:
        pusher.cancel()
        with contextlib.suppress(asyncio.CancelledError, asyncio.TimeoutError, ConnectionError):
            await pusher
        request.app["sockets"].discard(ws)
        await ws.close()
    return ws


async def _close_sockets(app: web.Application) -> None:
    for ws in set(app["sockets"]):
        await ws.close(code=WSCloseCode.GOING_AWAY, message=b"server shutdown")


def make_app(source: Source) -> web.Application:
    """The web application serving `source`: the page, /api/scene, /api/status and /ws."""
    app = web.Application()
    app["source"] = source
    app["sockets"] = set()
    app.router.add_get("/", _index)
    app.router.add_get("/api/scene", _scene)
    app.router.add_get("/api/status", _status)
    app.router.add_get("/ws", _websocket)
    app.router.add_static("/static", STATIC)
    app.on_shutdown.append(_close_sockets)
    return app


@dataclass(frozen=True)
class Address:
    """Where the server listens."""

    host: str
    port: int

    @property
    def url(self) -> str:
        """The page's URL (an IPv6 host in brackets)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"


async def _serve(source: Source, host: str, port: int, ready: Callable[[Address], None]) -> None:
    family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
    sock = socket.create_server((host, port), family=family)
    runner = web.AppRunner(make_app(source), handle_signals=False)
    await runner.setup()
    try:
        await web.SockSite(runner, sock).start()
        ready(Address(host, int(sock.getsockname()[1])))
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await stop.wait()
    finally:
        await runner.cleanup()


def serve(source: Source, host: str, port: int, ready: Callable[[Address], None]) -> None:
    """Serve the page until SIGINT/SIGTERM.

    Serve the page until SIGINT/SIGTERM; `ready` gets the bound address (port 0: the OS picks).
    Closes `source` on the way out. Raises OSError when the address cannot be bound."""
    try:
        asyncio.run(_serve(source, host, port, ready))
    finally:
        source.close()
