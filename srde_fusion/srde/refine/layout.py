"""Layout of the lobe model's parameter vector ``theta``.

``theta = (tilt_1, tilt_2, offset_m, log_width, tail, foreshortening, specular, diffuse,
level)``: three plane parameters, three shape parameters, three intensities.
"""

from __future__ import annotations

# Layout of the parameter vector theta.
_N_PLANE = 3
_I_WIDTH, _I_TAIL, _I_FORE = 3, 4, 5
_I_SPEC, _I_DIFF, _I_LEVEL = 6, 7, 8
_N_PARAMS = 9
