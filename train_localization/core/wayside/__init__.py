"""Wayside functions built on the detection systems of seed 004: the combined track-circuit
and axle-counter occupancy (section 4.2), the catenary of a neutral-section changeover and
its controller (section 4.1, Fig. 5-6), and the on-board / wayside cross-check."""
