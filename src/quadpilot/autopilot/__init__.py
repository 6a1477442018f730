"""The autopilot side of a flight, as a PX4 vehicle runs it, around a policy from `runtime`:

- `node`: the MAVLink node that flies a policy against a PX4-API simulator (one receive point,
  one actuator message per simulation step), as `node_config` says; `flight`: one episode, one
  handler per message type; `flight_log`: what a flight recorded;
- `dead_reckoning`: the node's own estimate from HIL_SENSOR; `state_loss`: what flies on it while
  the state stream is silent (the policy, a hold, a landing);
- `commander`: arming, mode switching, link-loss failsafe, one table of message handlers;
  `commands`: one function per command a ground station sends, in one table;
  `modes`: the navigator's flight modes, one class each as PX4's navigator has them (Takeoff, Land,
  Return, Loiter, Mission); `navigator`: flies a mode's legs; `setpoint`: where the policy is asked
  to fly;
- `mission_protocol`, `param_protocol` and `ftp_protocol`: MAVLink's mission, parameter and file
  protocols; `policy_upload`: a policy.tar put on the vehicle's card, checked, then flown;
- `streams`: the telemetry a ground station sees; `ground_station`: the node's ground-station socket.

Imports numpy, pymavlink and `core`, `link`, `runtime`: never torch or gymnasium.
"""
