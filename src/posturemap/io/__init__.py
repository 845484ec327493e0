"""Files in and out: BVH, map files (format and validation), atomic writes, glTF and previews.

Every reader validates what it reads before allocating and raises :class:`posturemap.UserError`
naming the file; every writer writes atomically (temp file, fsync, rename).
"""
