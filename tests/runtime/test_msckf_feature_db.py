"""Feature database: every operation against a plain model (per id, a list of (t, uv, xn) rows)."""
from __future__ import annotations

import numpy as np

from runtime.msckf.feature_db import FeatureDatabase


def _model_rows(db: FeatureDatabase) -> dict[int, list[tuple]]:
    return {fid: [(t, tuple(u), tuple(x)) for t, u, x in zip(tr.t_ns, tr.uv, tr.xn, strict=True)]
            for fid, tr in db.tracks.items()}


def test_random_operations_agree_with_a_list_model() -> None:
    """Frames of overlapping ids, removals, keep-only-last, drops of old times and of a middle time: the
    database holds exactly the model's rows, empty tracks are gone, and the creation order is kept."""
    rng = np.random.default_rng(5)
    db = FeatureDatabase()
    model: dict[int, list[tuple]] = {}
    t = 0
    times: list[int] = []
    for _step in range(400):
        t += int(rng.integers(1, 4)) * 50_000_000
        ids = np.unique(rng.integers(0, 60, int(rng.integers(0, 30))))
        if rng.random() < 0.1 and ids.size:
            ids = np.concatenate([ids, ids[:2]])      # a duplicate id in one frame: the first row counts
        uv = rng.uniform(0, 700, (ids.size, 2))
        xn = rng.uniform(-1, 1, (ids.size, 2))
        db.add(t, ids, uv, xn)
        times.append(t)
        for fid, u, x in zip(ids.tolist(), uv.tolist(), xn.tolist(), strict=True):
            rows = model.setdefault(fid, [])
            if not rows or rows[-1][0] != t:
                rows.append((t, tuple(u), tuple(x)))
        op = rng.random()
        live = sorted(model)
        if op < 0.15 and live:
            fid = int(rng.choice(live))
            db.remove(fid)
            model.pop(fid)
        elif op < 0.3 and live:
            some = [int(f) for f in rng.choice(live, size=min(5, len(live)), replace=False)]
            db.keep_only_last_of(some)
            for fid in some:
                model[fid] = model[fid][-1:]
        elif op < 0.6 and len(times) > 3:
            cut = times[int(rng.integers(0, len(times)))]
            db.drop_older_than(cut)
            model = {f: [r for r in rows if r[0] >= cut] for f, rows in model.items()}
            times = [x for x in times if x >= cut]
        elif op < 0.75 and len(times) > 2:
            mid = times[int(rng.integers(0, len(times)))]
            db.drop_time(mid)
            model = {f: [r for r in rows if r[0] != mid] for f, rows in model.items()}
            times.remove(mid)
        model = {f: rows for f, rows in model.items() if rows}
        assert _model_rows(db) == model
    # creation counts increase in the database's order (the SLAM promotion order relies on it)
    created = [tr.created for tr in db.tracks.values()]
    assert created == sorted(created) and len(set(created)) == len(created)


def test_the_time_index_holds_only_times_still_in_the_window() -> None:
    """Dropping and clearing also empty the per-time index (its memory stays bounded by the window)."""
    db = FeatureDatabase()
    for k in range(50):
        db.add(10 * k, np.array([k, k + 1]), np.zeros((2, 2)), np.zeros((2, 2)))
        db.drop_older_than(10 * (k - 4))
    assert sorted(db._ids_at) == [450, 460, 470, 480, 490]
    db.drop_time(470)
    assert sorted(db._ids_at) == [450, 460, 480, 490]
    db.clear()
    assert db._ids_at == {} and db.tracks == {}
