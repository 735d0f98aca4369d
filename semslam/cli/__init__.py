"""The ``semslam`` command line. One module ``cmd_<stage>.py`` per stage registers its sub-commands;
see :mod:`semslam.cli.main`."""
