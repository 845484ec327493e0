"""The character: quaternions, skeletons, motions, joint-name knowledge and the compiled kernels.

Everything else builds on these plain-array types; nothing here imports from the other
subpackages.
"""
