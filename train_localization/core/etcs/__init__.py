"""The ETCS location model on top of the fused state (docs/etcs.md): the track's balise groups
and linking (``track_data``), the location report relative to the last relevant balise group
with its safe front ends (``location``), the expectation windows of linking (``linking``), the
odometer monitoring (``odometer``), and the supervision to an end of authority that uses them
(``supervision``). The shared records are in ``records``."""
