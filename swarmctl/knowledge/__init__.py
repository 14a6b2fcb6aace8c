"""Knowledge sharing as one unit: what a vehicle knows, how it travels, how it is exchanged.

`model.py` (Knowledge: one vehicle's map with a semilattice merge; Delta, Detection), `codec.py`
(the TUNNEL payloads 32800-32803 on the wire), `exchange.py` (KnowledgeExchange: publish deltas and
digests, answer requests, merge). See docs/knowledge.md.
"""
