"""The contracts every layer shares and that depend on no layer of theirs: the mission schema, the
local frame, detections and the wire format, keys and signing, argument types and entry helpers."""
