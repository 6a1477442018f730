"""The autopilot side of a flight, as a PX4 vehicle runs it, around a policy from `runtime`:

- `node`: the MAVLink node that flies a policy against a PX4-API simulator (one receive point,
  one actuator message per simulation step) and `flight_log`, what a flight recorded;
- `commander`: arming, mode switching, link-loss failsafe, one table of message handlers;
  `commands`: one function per command a ground station sends, in one table;
  `modes`: the navigator's flight modes, one class each as PX4's navigator has them (Takeoff, Land,
  Return, Loiter, Mission); `navigator`: flies a mode's legs; `setpoint`: where the policy is asked to fly;
- `mission_protocol` and `param_protocol`: MAVLink's mission and parameter protocols;
- `streams`: the telemetry a ground station sees; `ground_station`: the node's ground-station socket.

Imports numpy, pymavlink and `core`, `link`, `runtime`: never torch or gymnasium.
"""
