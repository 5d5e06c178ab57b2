"""Reference durations for `cargo bench -p host-sim --bench trajectory` (not part of the product).

Reads JSON moves on stdin: [{"from": [..], "to": [..], "velocity": [..], "acceleration": [..],
"jerk": [..]}, ...] (per-axis limits, as Ruckig takes them), plans each rest-to-rest move with
the reference Ruckig (pip package `ruckig`) with phase synchronisation (all axes in step, so a
straight line stays straight), and prints the durations as a JSON list on stdout.
"""
import json
import sys

from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory

out = []
for move in json.load(sys.stdin):
    dofs = len(move["from"])
    inp = InputParameter(dofs)
    inp.current_position = move["from"]
    inp.current_velocity = [0.0] * dofs
    inp.current_acceleration = [0.0] * dofs
    inp.target_position = move["to"]
    inp.target_velocity = [0.0] * dofs
    inp.target_acceleration = [0.0] * dofs
    inp.max_velocity = move["velocity"]
    inp.max_acceleration = move["acceleration"]
    inp.max_jerk = move["jerk"]
    inp.synchronization = Synchronization.Phase
    trajectory = Trajectory(dofs)
    result = Ruckig(dofs).calculate(inp, trajectory)
    if result not in (Result.Working, Result.Finished):
        sys.exit(f"ruckig refused move {move}: {result}")
    out.append(trajectory.duration)
json.dump(out, sys.stdout)
