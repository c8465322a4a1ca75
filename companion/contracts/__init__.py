"""The contracts every layer shares, which depend on no layer of their own.

The mission schema, the local frame, detections and the wire format, keys and signing, argument
types and entry helpers.
"""
