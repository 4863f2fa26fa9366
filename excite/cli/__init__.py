"""The ``excite`` command line (:mod:`.app`, one module per command) and the resident process
that answers the short commands at once (:mod:`.resident_process`). Importing this package costs
nothing: the ``excite`` script imports :mod:`.resident_process` first, standard library only."""
