"""The rig: its configuration and parameter coordinates (:mod:`.config`), rigs built from the
calibration files users already have (:mod:`.importers`), and the bundled rigs (``bundled/``)."""
