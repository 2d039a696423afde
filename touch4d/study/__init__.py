"""Studies: measure what touch adds to vision, with many participants (paper §6-7).

- `design`: study files (config/studies/*.yaml): tasks, stimuli, conditions, repetitions, practice,
  breaks, time limits, the run constraint; `load_study(path)`.
- `plan`: a participant's session from (study, participant id) alone: `plan_session`,
  `condition_order`, `participant_index`; `Trial` (one planned trial).
- `stimuli`: a trial's scene (`trial_scene`) and the same as a scene-file mapping (`scene_mapping`).

A `Trial` carries the fields of the agreed interface and `break_before` (a pause is offered before
it: every `break_every` trials within a block).
"""
