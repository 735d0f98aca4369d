"""The one progress convention (semslam._progress): False silent, True a bar, a callable gets (done, total)."""

from __future__ import annotations

from semslam._progress import progress_steps


def test_callable_gets_done_and_total_and_bool_is_silent_or_a_bar(capsys):
    calls = []
    with progress_steps(lambda d, t: calls.append((d, t)), 3, "x") as step:
        for _ in range(3):
            step()
    assert calls == [(1, 3), (2, 3), (3, 3)]
    with progress_steps(False, 3, "x") as step:
        step()
    assert capsys.readouterr().err == ""
    with progress_steps(True, 2, "things", "thing") as step:
        step()
        step()
    assert "things" in capsys.readouterr().err


def test_long_calls_report_through_it():
    """The Monte Carlo (runs x modes) and the database build (views) take the same ``progress``."""
    from semslam.experiments.montecarlo import run_montecarlo
    from semslam.simulation.synthetic_views import synthetic_shape_views
    from semslam.recognition import build_database

    calls, lines = [], []
    run_montecarlo(1, modes=("dr", "position"), source="synthetic", loops=1, progress=lambda d, t: calls.append((d, t)),
                   log=lines.append)
    assert calls == [(1, 2), (2, 2)] and len(lines) == 2 and lines[0].startswith("run 1/1 dr: ATE")
    views, classes = synthetic_shape_views(2, n_points=150, seed=1)
    seen = []
    build_database(views, classes, seed=0, progress=lambda d, t: seen.append(d), esf_n_samples=500)
    assert seen == list(range(1, len(views) + 1))
