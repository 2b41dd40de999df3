"""The web console (``monitor console``, docs/console.md): an optional, separate process.

It follows the cell's signed commands over Zenoh like ``monitor watch`` (``live.py``), lists and
plays the incident recorder's clips through a narrow interface (``incidents.py``), and edits the
zone file with the same validation and atomic save as ``monitor zones`` (``zones_api.py``);
edits need an operator credential (``auth.py``); an operator holding their reset key confirms the
cell clear from the live page (``confirm_clear.py``, ``confirm_routes.py``), the lost persons'
areas and the hidden pockets drawn over the live picture (``live_areas.py``). The safety loop
never depends on it: the console only subscribes, and ``monitor run`` never reads anything the
console writes while it runs (a changed zone file takes effect at the next start).

Starlette and uvicorn are the optional extra ``console``; nothing else imports this package.

May import: the cli (its own command's options), the adapters, the bus, the incidents and everything
under them.
"""
