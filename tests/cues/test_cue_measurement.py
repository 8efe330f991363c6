import pickle

import numpy as np
import pytest

from fusion_pf.cues.base import Measurement


def test_measurement_is_immutable_and_picklable():
    m = Measurement("colour", 1.5, 2.5, 0.7, {"area_px": 120, "roi": [0, 0, 10, 10]})
    with pytest.raises(TypeError):
        m.extras["area_px"] = 3
    back = pickle.loads(pickle.dumps(m))
    assert back == m and dict(back.extras) == {"area_px": 120, "roi": [0, 0, 10, 10]}
    np.testing.assert_array_equal(back.z, [1.5, 2.5])
