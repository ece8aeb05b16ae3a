"""The simulator: MuJoCo scene, rendering, the simulated driver and the Gymnasium env ``ArcCalib-v0``.

Also camera conventions (``camera``), distortion, the marker board, and ``env.ArcCalibEnv``. The GL
backend is chosen when the first renderer is created (``arc_env.robot.rendering``), not on import.
"""
