"""Camera frames: what a vehicle's downward detector reports, on the vehicle's Zenoh key.

The bundled simulator publishes one `CameraFrame` per simulated camera exposure; a real
aircraft's detector publishes the same message on the same key. The wire form is msgpack of the
struct (field names as map keys). `decode` turns bytes into a frame and `check` rejects frames
that decode but make no sense (wrong version, unknown vehicle, non-finite or out-of-range values).
"""

from __future__ import annotations

import math

import msgspec

from companion.contracts.wire import MsgpackCodec

FRAME_VERSION = 1
MAX_DETECTIONS = 4096


class DetectionError(ValueError):
    """A camera frame that must be dropped, with the reason."""


class CameraFrame(msgspec.Struct, frozen=True, kw_only=True):
    """One exposure: vehicle pose at `time_usec` (vehicle time) and the detections in its FOV.

    `alt` is metres above mean sea level, `heading` radians counter-clockwise from east (the
    core's convention), `detections` the (lat, lon) in degrees of each detected target's cell centre.
    """

    v: int = FRAME_VERSION
    uav: int
    time_usec: int
    lat: float
    lon: float
    alt: float
    heading: float
    detections: tuple[tuple[float, float], ...] = ()


def camera_key(key_prefix: str, mission_name: str, uav: int) -> str:
    """The Zenoh key expression of vehicle `uav`'s camera frames."""
    return f"{key_prefix}/{mission_name}/uav/{uav}/camera"


_codec: MsgpackCodec[CameraFrame] = MsgpackCodec(CameraFrame, DetectionError, "camera frame")
encode = _codec.encode
decode = _codec.decode  # raises DetectionError for anything undecodable


def _valid_lat_lon(lat: float, lon: float) -> bool:
    return math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180


def check(frame: CameraFrame, n_uavs: int) -> None:
    """Raise DetectionError unless `frame` is a well-formed frame of a mission with n_uavs vehicles."""
    if frame.v != FRAME_VERSION:
        raise DetectionError(f"frame version {frame.v}, expected {FRAME_VERSION}")
    if not 0 <= frame.uav < n_uavs:
        raise DetectionError(f"unknown uav {frame.uav}")
    if frame.time_usec < 0:
        raise DetectionError("negative time")
    if not _valid_lat_lon(frame.lat, frame.lon) or not math.isfinite(frame.alt + frame.heading):
        raise DetectionError("bad pose")
    if len(frame.detections) > MAX_DETECTIONS:
        raise DetectionError(f"{len(frame.detections)} detections (max {MAX_DETECTIONS})")
    if not all(_valid_lat_lon(lat, lon) for lat, lon in frame.detections):
        raise DetectionError("bad detection coordinates")


def decode_checked(data: bytes, n_uavs: int) -> CameraFrame:
    """`decode` then `check`: the one call a subscriber needs."""
    frame = decode(data)
    check(frame, n_uavs)
    return frame
