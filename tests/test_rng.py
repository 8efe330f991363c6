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


def test_bit_generator_choice_for_seeds_only():
    a = as_rng(3, bit_generator=np.random.SFC64)
    assert isinstance(a.bit_generator, np.random.SFC64)
    assert a.standard_normal(4).tolist() == as_rng(3, bit_generator=np.random.SFC64).standard_normal(4).tolist()
    assert as_rng(3).standard_normal(4).tolist() == np.random.default_rng(3).standard_normal(4).tolist()
    g = np.random.default_rng(1)
    assert as_rng(g, bit_generator=np.random.SFC64) is g


def test_particle_filter_seed_uses_the_fast_generator():
    from fusion_pf.filter.pf import ParticleFilter

    assert isinstance(ParticleFilter(n_particles=10, rng=4).rng.bit_generator, np.random.SFC64)
