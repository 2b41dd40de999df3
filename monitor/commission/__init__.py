"""Commissioning: the walk test (``walk``, ``floor``, ``pictures``, ``walk_video``) and the
commissioning report with its checksum (``report``, ``record``). See docs/commissioning.md."""
