"""Commissioning: the walk test (``walk``, ``floor``, ``pictures``, ``walk_video``) and the
commissioning report with its checksum (``report``, ``record``). See docs/commissioning.md.

May import: the service's set-up and commissioned record (``monitor.service``), the replay, the
config and everything under them; never the cli or the console.
"""
