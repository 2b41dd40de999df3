"""Commissioning: the walk test (``walk``, ``floor``, ``pictures``, ``walk_video``, ``recording``:
recording a walk, ``truth``, ``walk_scene``: generated walks), its verdict per zone and camera
(``verdict``), and the commissioning report, signed with the commissioner's key (``inputs``
gathers it, ``details`` and ``open_warnings`` are its figures and warnings, ``report`` and
``report_details`` render it, ``html`` the pieces, ``unseen`` the zones' unseen floor with its
cost and a camera that would see it). See docs/commissioning.md.

May import: the service's set-up and commissioned record (``monitor.service``), the replay, the
config and everything under them; never the cli or the console.
"""
