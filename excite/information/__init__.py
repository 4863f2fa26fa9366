"""The information of a drive: the problem (every factor linearised, :mod:`.problem`), how a
drive is closed (gauge, last keyframe, bias walk, nuisances: :mod:`.closure`), the elimination of
the trajectory (:mod:`.elimination`, compiled in :mod:`.kernels`) and the dense reference and
export (:mod:`.dense`)."""
