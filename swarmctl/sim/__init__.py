"""The simulated outside world: everything that stands in for real vehicles, radios and detectors.

`autopilot.py` the mock ArduCopter / PX4 (a real MAVLink endpoint), `fence.py` its geofence,
`radio.py` the loopback radio with the channel model's losses, `detector.py` the simulated detector,
`swarm.py` a mock swarm with hidden targets for the demo and the tests, `cli.py` `swarmctl mock-vehicle`.
The controller (swarmctl.mission) talks to these exactly as to real vehicles and never reads the truth.
"""
