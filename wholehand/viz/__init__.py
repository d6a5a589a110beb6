"""Visualisation: a meshcat scene of hand, object, contacts and force arrows; replays; plots.

- :class:`wholehand.viz.scene.SceneViewer`: live (``SceneViewer.live``) or recorded
  (``SceneViewer.offline``) scene, updated with ``update(q, wMo, contact_p, contact_f)``.
- :func:`wholehand.viz.replay.write_html`: a run record as a standalone HTML animation.
- :func:`wholehand.viz.plots.plot_run`: a run record as a four-panel PNG.

Submodules import meshcat and matplotlib; import them where needed.
"""
