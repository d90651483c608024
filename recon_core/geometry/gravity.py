"""Gravity in the map frame: the one convention every stage shares.

The map frame is gravity aligned with z up (REP-103/105 ``map``): ``UP`` is +z and the gravity
direction ``g`` of the paper's Eq. (1) is -z. Inputs whose world frame is not gravity aligned are
re-framed before they reach the stages.
"""

from __future__ import annotations

import numpy as np

#: Up direction of the map frame and of every CAD model's canonical frame.
UP = np.array([0.0, 0.0, 1.0])
UP.setflags(write=False)
#: Gravity direction g of Eq. (1) in the map frame.
GRAVITY = -UP
GRAVITY.setflags(write=False)
