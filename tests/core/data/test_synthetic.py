"""The embedded synthetic route: deterministic, fast, learnable but not trivial."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import numpy as np
import pytest

from vprsnn_export.config import PreprocessConfig
from vprsnn_export.data import synthetic
from vprsnn_export.data.preprocess import preprocess_images
from vprsnn_export.data.synthetic import SYNTHETIC_TRAVERSALS, synthetic_fingerprint, synthetic_route
from vprsnn_export.errors import InvalidValueError


def test_shapes_and_dtype() -> None:
    route = synthetic_route(7, ("summer", "winter", "spring", "fall"))
    assert set(route) == {"summer", "winter", "spring", "fall"}
    for images in route.values():
        assert images.shape == (7, 32, 64) and images.dtype == np.uint8
        assert images.std() > 10
    assert synthetic_route()["summer"].shape == (60, 32, 64)


def test_bit_for_bit_deterministic() -> None:
    first, second = synthetic_route(30, seed=3), synthetic_route(30, seed=3)
    assert all(np.array_equal(first[name], second[name]) for name in first)
    other = synthetic_route(30, seed=4)
    assert not np.array_equal(first["summer"], other["summer"])


def test_places_do_not_depend_on_route_length_or_traversal_order() -> None:
    long = synthetic_route(120, ("winter", "summer"))
    short = synthetic_route(45, ("summer", "winter"))
    for name in short:
        assert np.array_equal(short[name], long[name][:45])


def test_seasons_differ_from_each_other() -> None:
    route = synthetic_route(10, SYNTHETIC_TRAVERSALS)
    for a in SYNTHETIC_TRAVERSALS:
        for b in SYNTHETIC_TRAVERSALS:
            if a < b:
                assert not np.array_equal(route[a], route[b])


def test_neighbouring_places_look_alike() -> None:
    images = synthetic_route(40)["summer"].astype(np.float64)
    near = np.abs(images[1:] - images[:-1]).mean()
    far = np.abs(images[20:] - images[:-20]).mean()
    assert near < 0.75 * far


def test_the_same_route_in_a_fresh_interpreter() -> None:
    """No dependence on hash randomisation, import order or global RNG state: another process, same bytes."""
    code = (
        "import hashlib; from vprsnn_export.data.synthetic import synthetic_route; r = synthetic_route(30); "
        "print(hashlib.sha256(b''.join(r[t].tobytes() for t in sorted(r))).hexdigest())"
    )
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    route = synthetic_route(30)
    assert other == hashlib.sha256(b"".join(route[t].tobytes() for t in sorted(route))).hexdigest()


def test_sad_nearest_neighbour_is_well_above_chance_but_not_perfect() -> None:
    n = 60
    route = synthetic_route(n)
    reference = preprocess_images(route["summer"], PreprocessConfig())
    query = preprocess_images(route["winter"], PreprocessConfig())
    distances = np.abs(query[:, None, :] - reference[None, :, :]).sum(axis=2)
    top1 = float((distances.argmin(axis=1) == np.arange(n)).mean())
    assert 5.0 / n < top1 < 1.0, top1
    assert 0.5 <= top1 <= 0.9, top1  # the documented difficulty (measured 0.72 with version 1)


def test_fingerprint() -> None:
    digest = synthetic_fingerprint(60, ("summer", "winter"), 0)
    canonical = f"vprsnn-synthetic-route|v={synthetic.SYNTHETIC_VERSION}|places=60|traversals=summer,winter|seed=0"
    assert digest == hashlib.sha256(canonical.encode()).hexdigest()  # the documented formula, not any hex string
    assert digest == synthetic_fingerprint(60, ("summer", "winter"), 0)
    assert digest != synthetic_fingerprint(61, ("summer", "winter"), 0)
    assert digest != synthetic_fingerprint(60, ("winter", "summer"), 0)
    assert digest != synthetic_fingerprint(60, ("summer", "winter"), 1)


def test_fingerprint_includes_version(monkeypatch: pytest.MonkeyPatch) -> None:
    before = synthetic_fingerprint()
    monkeypatch.setattr(synthetic, "SYNTHETIC_VERSION", synthetic.SYNTHETIC_VERSION + 1)
    assert synthetic_fingerprint() != before


@pytest.mark.parametrize("kwargs", [{"n_places": 0}, {"traversals": ("autumn",)}, {"traversals": ()}, {"seed": -1}])
def test_bad_arguments(kwargs: dict) -> None:
    with pytest.raises(InvalidValueError):
        synthetic_route(**kwargs)
