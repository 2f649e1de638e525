"""Sharding a long road over several association nodes: regions of stations
(:mod:`.regions`), the hand-off of tracks at the borders (:mod:`.desk`), the one view of
every shard's tracks (:mod:`.merge`), and the whole offline (:mod:`.sharded`).
"""
