"""MAVSDK-Python 4.x (ctypes API, asyncio wrapper) flies a simulated vehicle to a point."""

from __future__ import annotations

import asyncio
import signal
from pathlib import Path

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from tests.sim.conftest import ARRIVED_M, distance_m, offset, write_mission


async def _fly(port: int) -> None:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(f"udpout://127.0.0.1:{port}")
        system = await sdk.first_autopilot(timeout_s=60.0)
        assert system is not None
        while not await system.is_connected():
            await asyncio.sleep(0.1)
        telemetry, action = TelemetryAsync(system), ActionAsync(system)
        async for health in telemetry.subscribe_health():
            if health.is_global_position_ok and health.is_home_position_ok and health.is_armable:
                break
        position = await anext(aiter(telemetry.subscribe_position()))
        assert abs(position.relative_altitude_m - 100.0) < 1.0
        async for armed in telemetry.subscribe_armed():
            assert armed is False
            break
        async for mode in telemetry.subscribe_flight_mode():
            assert mode is not None
            break
        await action.arm()
        async for armed in telemetry.subscribe_armed():
            if armed:
                break
        lat, lon = offset(position.latitude_deg, position.longitude_deg, 500.0, 300.0)
        await action.goto_location(lat, lon, position.absolute_altitude_m, 0.0)
        async for p in telemetry.subscribe_position():
            if distance_m(p.latitude_deg, p.longitude_deg, lat, lon) < ARRIVED_M:
                break


def test_mavsdk_goto(tmp_path: Path, start_sim) -> None:
    path, ports, _ = write_mission(tmp_path, n=1)
    sim = start_sim(path, "--speedup", "5", "--no-camera", n=1)
    asyncio.run(asyncio.wait_for(_fly(ports[0]), timeout=120))
    rc, stats = sim.stop(signal.SIGINT)
    assert stats["input"]["frames"] > 0
    assert rc == 0
