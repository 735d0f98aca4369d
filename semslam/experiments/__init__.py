"""semslam.experiments: evaluation harnesses above the library (Monte Carlo of the filter, pose-accuracy and
recognition studies on simulated data, synthetic missions and views for tests and benchmarks)."""
