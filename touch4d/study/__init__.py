"""Studies: measure what touch adds to vision, with many participants (paper §6-7), and predict the
outcome with model observers before anyone is recruited.

- `design`: study files (config/studies/*.yaml): tasks, stimuli, conditions, repetitions, practice,
  breaks, time limits, the run constraint; `load_study(path)`. Each task kind is one `Task` subclass
  (`FrontElementTask`, `LookAlikesTask`, `TiltTask`; `task_kinds()`), the place of its keys and stimuli.
- `plan`: a participant's session from (study, participant id) alone: `plan_session`,
  `quick_plan` (`--quick`: one repetition per task x condition cell, i.e. every stimulus once per
  condition, no practice), `condition_order`, `participant_index`, `participant_ids(n)`; `Trial`.
- `stimuli`: a trial's scene (`trial_scene`) and the same as a scene-file mapping (`scene_mapping`);
  `stimulus_scene(study, task, stimulus, level, transform)` for any stimulus.
- `observer`: `ModelObserver(glove, study, noise=, visual_noise=, lapse=, seed=)` with `explore(trial,
  rng)` and `respond(trial, patterns | None, scene | None, rng)`; `every_sample_glove(glove)`.
- `simulate`: the offline simulation (no bus) into session folders; `table`: trials.csv (`COLUMNS`,
  `read_trials`); `analysis`: `touch4d study analyze`; `infotransfer`: bits from a confusion matrix
  (beside the bits its answers give shuffled) and predicted per glove.
- `conditions`: the conditions, declared once; `gate`: what a condition lets through now.
- `machine`: `TrialMachine`, a session's trial state machine without a bus (the study node wires it).
- a session folder: `store` (trials.csv, `TrialsFile`), `manifest` (manifest.json, `prepare_out`),
  `lock` (`SessionLock`: one writer), `measures` (exploration from bus samples); `session`: running
  one through the full stack (`run_session`, `run_simulation`).
- Planning before recruiting (docs/planning.md): `psychophysics` (the default touch noise from
  published thresholds), `pilotfit` (`touch4d study fit`), `power` (`touch4d study power`),
  `glovedesign` (`touch4d glove design`), all fanned out by `fanout` on Dask.

Beyond the first agreed interface: a `Trial` also carries `break_before` (a pause is offered before
it: every `break_every` trials within a block, never before a block's first nor with under half a
stretch left before the block's end); the model observer's constructor also takes `exploration`,
`train_scenes`, `train_positions` and `view_scenes` (how much it is trained: fewer for a quick run);
`trial_row`-style writers use `table.COLUMNS`, the one declaration of the trials.csv columns that
the analysis reads.
"""
