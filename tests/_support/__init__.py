"""Helpers shared by the tests (not tests themselves): where the shared data is (:mod:`.shared`), ROS 1 processes
and messages (:mod:`.ros1`), synthetic scenes and parts (:mod:`.scenes`). Imported as ``tests._support.<module>``: the
repository root is on ``sys.path`` through ``pythonpath`` in ``pyproject.toml`` (tests run with
``--import-mode=importlib``, which puts no test folder on it)."""
