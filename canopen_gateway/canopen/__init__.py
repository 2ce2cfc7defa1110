"""CANopen facts, defined once: CiA 301 (COB-IDs, object indexes, abort codes, the error
register), CiA 305 (LSS), the pre-defined connection set in words, EMCY decoding, NMT states,
object references and the texts of codes. Pure data and functions: every layer reads them.

Imports: nothing of the gateway (each module names its own siblings).
"""
