"""Persons across frames and cameras: who is who, and where a lost person could be.

Owns: persistent person ids and the holds of persons lost near zones (``tracks``, ByteTrack from
supervision; what it hands out in ``track_types``, what it keeps of each person in
``track_record``), where a lost person could be until a working
camera has seen it free (``whereabouts``, on the image's grid of foot positions:
``foot_grid``; a lost person seen walking out of it: ``exits``), the person counts of hidden
pockets enclosed by seen floor (``pockets``), one person id across the cameras of a cell
(``cell_persons``), the hand-over of holds between the monitors of one cell (``handover``) and
the persons seen again where their hold had ended as seen free: a detector gap (``gaps``).

May import: ``monitor.zones`` (the hand-over's zones), ``monitor.wire`` (roles), the building
blocks and the bottom layer. Never the pipeline that runs it.
"""
