"""What a step leaves for people to read: the command and alert records and the annotated frame.

Owns: the records of ``events.jsonl`` shared by the replay and the incident recorder
(``events``), and the annotated video frame (``annotate``: zones, persons, the decision;
``areas_draw``: the lost persons' areas and the unseen floor, also drawn by the console and
``zones preview``).

May import: ``monitor.pipeline`` (a step's result), ``monitor.health`` and ``monitor.zones`` for
drawing, the building blocks and the bottom layer. Never the driver, the bus or their callers.
"""
