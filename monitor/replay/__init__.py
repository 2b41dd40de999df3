"""Offline runs of the live pipeline: ``monitor replay video.mp4`` and the scenario suite.

Owns: the replay on a video's own clock with its events and annotated video (``video``), and
the scenario suite that runs synthetic scenes with ground truth through the pipeline: its scene
sets (``scenarios``, ``pocket_scenes``), the runner that scores a scene (``scenario_run``) and
the judgement of holds alive at the end (``end_holds``).

May import: the driver, ``monitor.records``, ``monitor.incidents`` and everything under them.
Never ``monitor.service`` (they share the driver), the cli or the console.
"""

from monitor.replay.video import ReplaySettings, ReplaySummary, replay

__all__ = ["ReplaySettings", "ReplaySummary", "replay"]
