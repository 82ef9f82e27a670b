#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""gr-thrumapper: through-wall building mapping with a bistatic OFDM array radar.

The C++ core (radar description, manifolds, JADE) and blocks come from the pybind11
extension; the Python modules add the survey I/O, the simulated building and the tools.
"""

# import pybind11 generated symbols into the thrumapper namespace
try:
    from .thrumapper_python import *  # noqa: F401,F403
except ModuleNotFoundError:
    pass
from . import scene, building_sim, evaluation, rx_calibration, tx_calibration
from .survey import Survey, SurveyFormatError, read_survey, write_survey, group_frames_by_pose
from .survey_blocks import survey_source, survey_sink
from .building_channel import building_channel
from .iq_recording import iq_sink, iq_source
from .wall_fusion import wall_fusion, WallFusion, FusionSettings, RadarGeometry, FusedMap
from .live_map import live_map
