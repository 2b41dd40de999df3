"""What goes over the bus, as formats and rules, below every stage that sends or checks it.

Owns: Ed25519 keys and signatures (``signing``), files signed over every byte (``evidence``:
the commissioning report and record), the one bounded JSON decoder for bus payloads
(``payload``), what every signed request checks (``signed_requests``), how its answer is read
(``answers``), the bus's desk where requests wait for the pipeline's judgement
(``request_desk``: mutes, acceptances of objects), operator resets (``resets``), the consumer
rule for ``safety/command`` (``consumer``, ``cell_consumer``), the ``[bus]`` settings and key
expressions (``busconfig``), alert payloads and rate limits (``alerts``), the signature-check
budget (``verify_budget``) and a consumer's bounded inbox (``inbox``). Pure where it can be:
the live Zenoh edge that uses these is ``monitor.bus``.

May import: ``monitor.policy`` (the latch a reset answers) and the bottom layer (``types``,
``schema``, ``errors``). Never a stage, the pipeline or the bus above it.
"""
