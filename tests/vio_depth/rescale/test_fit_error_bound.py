"""A frame's own fit is ok only while its predicted relative depth error is within the bound."""

import numpy as np

from vio_depth.pipeline import FrameStatus, decide_frame_status
from vio_depth.rescale import FitSource, FitStatus, Rescaler, RescalerSettings


def _points(rng, n, noise):
    d = rng.uniform(0.2, 1.0, n)
    depth = 1.0 / (0.4 * d + 0.02)
    depth = depth * (1.0 + noise * rng.standard_normal(n))
    return d, depth


def test_a_certain_fit_is_ok_and_records_its_predicted_error():
    rng = np.random.default_rng(0)
    d, depth = _points(rng, 400, 0.01)
    disparity_map = rng.uniform(0.2, 1.0, (40, 60))
    res = Rescaler(RescalerSettings(temporal=None)).update(d, depth, disparity_map=disparity_map)
    assert res.source == FitSource.FRAME and res.predicted_error is not None and res.predicted_error < 0.02


def test_an_uncertain_fit_is_not_ok_and_says_why():
    rng = np.random.default_rng(1)
    d, depth = _points(rng, 12, 0.3)  # a dozen points 30 % off: the line is poorly known
    disparity_map = rng.uniform(0.2, 1.0, (40, 60))
    settings = RescalerSettings(temporal=None, max_fit_error=0.02)
    res = Rescaler(settings).update(d, depth, np.full(12, 0.3) * depth, disparity_map=disparity_map)
    assert res.raw.status == FitStatus.OK  # the robust fit itself found a line ...
    assert res.source == FitSource.NONE and res.fit is None  # ... but it is not trusted
    assert res.predicted_error > 0.02 and "max_fit_error" in res.reason
    assert decide_frame_status(FrameStatus.OK, res.source, res.raw.status) == FrameStatus.UNCERTAIN_FIT
    # with a looser bound the same frame is ok
    assert Rescaler(RescalerSettings(temporal=None, max_fit_error=0.2)).update(
        d, depth, np.full(12, 0.3) * depth, disparity_map=disparity_map).source == FitSource.FRAME
