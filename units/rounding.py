"""Rounding margins shared by the conservative tests of the tile test unit.

The sample tester works on float32 vertices (rounded by up to 2^-24 of their
magnitude, and lerped in float32): every float64 bound of the tile test and
its algorithm kernels is widened by ``F32_REL`` of the magnitudes of its
terms, so it stays conservative against that rounding, even for vertices
millions of pixels away. ``MARGIN_PX`` widens every tile by a pixel fraction.
"""

MARGIN_PX = 1.0 / 64.0
F32_REL = 1e-6
