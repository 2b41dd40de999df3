"""Package data: the demo cell (demo-cell.yaml, a link to zones/demo-cell.yaml in the source
tree) that `monitor demo` and the default `monitor run` use.

Imports nothing.
"""
