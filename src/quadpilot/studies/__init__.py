"""Studies: the experiments run on top of training, kept apart from it. `compare` (quad-compare:
the PPO-vs-Stable-Baselines3 sweep; its report in `compare_report`, the matched-settings table in
`matched_settings`), `sac_compare` (SAC against PPO on one plot), `robustness` (the disturbance
and parameter grid a policy is flown over) and `learning_montage` (the learning montage drawn
from a run's snapshots with `viz.render_montage`). Each imports `quadpilot.train` and the packages
below it; nothing outside this package imports it, so training never depends on a study.
"""
