"""Layout of the lobe model's parameter vector ``theta``.

``theta = (tilt_1, tilt_2, offset_m, log_width, tail, foreshortening, specular, diffuse,
level)``: three plane parameters, three shape parameters, three intensities.
"""

from __future__ import annotations

# Layout of the parameter vector theta.
N_PLANE = 3
I_WIDTH, I_TAIL, I_FORE = 3, 4, 5
I_SPEC, I_DIFF, I_LEVEL = 6, 7, 8
N_PARAMS = 9
