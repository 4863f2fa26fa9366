"""Measurement kinds: one module per kind, each declaring its rig entry, its calibration
quantities, its math once (in CasADi), its compiled kernel and its simulation
(:mod:`excite.factors.base` states the protocol and keeps the registry). Importing this package
registers the built-in kinds, in this order — the order of the rows of J, and of θ's columns
after the sensors' —: the IMU, rear-axle wheel encoders, the non-holonomic constraint, lidar and
camera odometry, a lidar's road plane, GNSS antennas, a car's CAN wheel speeds and steering (Ackermann), Doppler radar
ego-velocity. A kind of one's own is a module like these that calls
:func:`~excite.factors.base.register`."""

from . import ackermann, base, gnss, ground, imu, nonholonomic, odometry, radar, wheel

for _kind in (imu.Imu(), wheel.Wheel(), nonholonomic.NonHolonomicConstraint(), odometry.Odometry(),
              ground.GroundPlane(), gnss.Gnss(),
              ackermann.Ackermann(), radar.Radar()):
    base.register(_kind)
