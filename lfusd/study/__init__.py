"""`lfusd rig-study`: which light-field camera arrangement suits a scene and a task.

The study is an experiment on top of the rest of lfusd, so it may use every part of it
(authoring, rendering, reading, evaluating), like the commands:

- :mod:`.candidates`: every combination of baselines, spacings, layouts and axes as a
  :class:`~lfusd.camera.RigSpec` at the stage's rig position(s); the union of their distinct
  cameras (one camera = one rig-local pose and lens), authored as one rig per position so a
  camera that several candidates share is rendered once;
- :mod:`.sweep`: a plane sweep over arbitrary camera poses (homographies of fronto-parallel
  planes), the estimator behind disparity and view reconstruction for any layout and axes;
- :mod:`.score`: a candidate's scores from the rendered cameras: disparity error by depth band,
  the per-view redundancy (held-out view reconstructed from its grid neighbours), coverage and
  occlusion holes, parallax, scene-flow error;
- :mod:`.report`: ranking, the terminal table, ``report.md``, heat maps and plots;
- :mod:`.run`: the study folder (resumable), rendering, scoring and ``--apply``.
"""
