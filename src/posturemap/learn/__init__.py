"""Learning the maps: posture vectors in four bone classes, the growing map, the estimator.

:class:`~posturemap.learn.model.PostureMap` is the scikit-learn-style estimator (``fit``,
``partial_fit``, ``predict``, ``score``, ``save``/``load``) over one
:class:`~posturemap.learn.upm.UniformPostureMap` per bone class.
"""
