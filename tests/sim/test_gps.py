"""Simulated urban-canyon GPS: seedable, clean in the open, jumpy down in the streets."""

from __future__ import annotations

import numpy as np

from skyrecon.sim.generate import generate_city
from skyrecon.sim.gps import UrbanCanyonGps, UrbanGpsSettings, simulate_gps


def _street_track(city, altitude: float, n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    ys = city.street_centers[1]
    y = float(ys[len(ys) // 2])
    x0, _, x1, _ = city.extent
    t = np.arange(n) * 0.2
    x = np.linspace(x0 + 10, x1 - 10, n)
    return t, np.column_stack([x, np.full(n, y), np.full(n, altitude)])


def test_deterministic_in_the_seed():
    city = generate_city(2, size_m=120.0)
    t, p = _street_track(city, 12.0, 60)
    a = simulate_gps(city, t, p, seed=5)
    b = simulate_gps(city, t, p, seed=5)
    c = simulate_gps(city, t, p, seed=6)
    assert [f.time_s for f in a] == [f.time_s for f in b]
    assert np.array_equal([f.position for f in a], [f.position for f in b])
    assert not np.array_equal([f.position for f in a], [f.position for f in c][: len(a)])


def test_open_sky_has_no_jumps_and_street_canyons_do():
    city = generate_city(2, size_m=120.0, max_height_m=60.0)
    settings = UrbanGpsSettings(rate_hz=5.0, jump_rate_hz=0.5)
    high_t, high_p = _street_track(city, city.max_height_m + 30.0)
    rx = UrbanCanyonGps(city, seed=1, settings=settings)
    errs = []
    for t, p in zip(high_t, high_p):
        f = rx.fix(t, p)
        assert f is not None
        errs.append(np.linalg.norm((f.position - p)[:2]))
    assert max(b for _, b, _ in rx.log) == 0.0 and not any(j for _, _, j in rx.log)
    assert np.median(errs) < 6.0  # bias (2 m) + noise (1 m), horizontal

    low_t, low_p = _street_track(city, 8.0)
    rx = UrbanCanyonGps(city, seed=1, settings=settings)
    fixes = [rx.fix(t, p) for t, p in zip(low_t, low_p)]
    blocked = np.array([b for _, b, _ in rx.log])
    jumping = np.array([j for _, _, j in rx.log])
    assert blocked.max() > settings.multipath_at
    assert jumping.any()
    big = [np.linalg.norm((f.position - p)[:2]) for f, p in zip(fixes, low_p) if f is not None]
    assert max(big) > 10.0  # a multipath jump of about 20 m
    # dropouts only where the sky is almost all blocked
    assert all(f is not None for f, b in zip(fixes, blocked) if b <= settings.dropout_at)
