"""Making transitions: requests, bases, keys from the maps, retrieval of real motion, feet.

:class:`~posturemap.synth.engine.TransitionEngine` holds prepared clips and makes one transition
per call from a :class:`~posturemap.synth.request.TransitionRequest`;
:func:`posturemap.synth.engine.transition` (``posturemap.transition``) is the one-call form.
"""
