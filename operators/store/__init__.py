"""What a session keeps of each setup, what an edit drops, and the bake on disk.

Modules
-------
registry      the setups of this session: one ``Runtime`` each, their status, their scene
invalidation  what an edit drops (cached frames), and the refresh after it
bake          bake and resume (``BakeJob``), bake directories, free
baked         a baked setup against its bake: settings changed since mark it outdated
"""
