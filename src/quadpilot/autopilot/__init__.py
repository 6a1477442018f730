"""The autopilot side of a flight, as a PX4 vehicle runs it, around a policy from `runtime`:

- `node`: the MAVLink node that flies a policy against a PX4-API simulator (one receive point,
  one actuator message per simulation step) and `flight_log`, what a flight recorded;
- `commander` (with `commands`): arming, modes and the commands a ground station sends;
  `navigator`: the flight modes that move the vehicle; `setpoint`: where the policy is asked to fly;
- `mission_protocol` and `param_protocol`: MAVLink's mission and parameter protocols;
- `streams`: the telemetry a ground station sees; `ground_station`: the node's ground-station socket.

Imports numpy, pymavlink and `core`, `link`, `runtime`: never torch or gymnasium.
"""
