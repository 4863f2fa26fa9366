"""The ``excite`` command line (:mod:`.app`, one module per command). Importing this package costs
nothing: the ``excite`` script imports :mod:`.app` and the module of the command it runs only."""
