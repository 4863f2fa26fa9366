"""Drivable plans: calibration drives a person executes from cones and a sheet of instructions.

:mod:`.elements` (figure-eight, circles, slalom, straight run: geometry, cones, instructions),
:mod:`.plan` (a plan as data, what it builds into: course, cones, instructions, GeoJSON).
"""
