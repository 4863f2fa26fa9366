"""Motion: the nominal trajectory of a drive (:mod:`.trajectory`), the ground vehicle's
kinematics and limits (:mod:`.vehicle`), geometric paths to control profiles (:mod:`.paths`)
and the reference maneuvers and random candidates (:mod:`.maneuvers`)."""
