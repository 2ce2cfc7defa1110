"""Error control (CiA 301 7.2.8.3.2): the heartbeat consumer and the node-guarding master
(``supervision``), what the node is expected to report per lifecycle step and NMT command
(``node_supervision``), and the process-data link check by the guarding bit (``guarding_bit``,
AP05 manual 5.5.5).

Imports: states, cia301. No I/O, no clock of their own.
"""
