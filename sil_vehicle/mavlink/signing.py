"""Compatibility re-export: MAVLink 2 signing lives in trq_wire.signing (shared with the
controller). Kept for the tools that import it from here (tools/mavclient.py,
tools/inject_fault.py); new code imports trq_wire.signing."""

from trq_wire.signing import (READ_ONLY_IDS, SignatureCheck, SigningKeyError, load_key,
                              sign_outgoing)

__all__ = ["READ_ONLY_IDS", "SignatureCheck", "SigningKeyError", "load_key", "sign_outgoing"]
