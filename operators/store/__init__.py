"""What a session keeps of each setup, what an edit drops, and the bake on disk.

Modules
-------
registry      the setups of this session: one ``Runtime`` each (one part per owner), their scene
playback      the playback cache: frames kept, dropped, held
report        what the panel shows of a setup: status, outdated mark, statistics; errors
invalidation  what an edit drops (cached frames), and the refresh after it
bake          bake and resume (``BakeJob``; ``ToBake``: the spine's sink), directories, free
baked         a baked setup against its bake: settings changed since mark it outdated
"""
