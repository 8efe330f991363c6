import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.rng import as_rng


def test_generator_is_passed_through():
    g = np.random.default_rng(1)
    assert as_rng(g) is g


def test_int_seed_is_reproducible():
    assert as_rng(7).integers(0, 10**9, 5).tolist() == as_rng(7).integers(0, 10**9, 5).tolist()
    assert as_rng(7).integers(0, 10**9, 5).tolist() != as_rng(8).integers(0, 10**9, 5).tolist()


@pytest.mark.parametrize("bad, message", [(-1, "non-negative int, got -1"), ("3", "got str"), (True, "got bool")])
def test_bad_rng(bad, message):
    with pytest.raises(InputError, match=message):
        as_rng(bad)
