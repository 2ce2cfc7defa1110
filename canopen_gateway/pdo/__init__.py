"""Process data objects (CiA 301 7.4.5, 7.5.2.35-38) as the gateway uses them once a node's
layout is known: the precompiled codecs of the hot path (``codec``), the values read after NMT
start for PDOs that send only on change (``refresh``) and the read-back of the mapping objects
before NMT start (``verify``). The layout itself comes from the profile (``profiles.layout``).

Imports: profiles, eds, objref, cia301. Never bus/, python-can, asyncio or a northbound module.
"""
