"""Session-wide set-up: nothing to do. The GL backend is chosen when a renderer is created
(``arc_env.robot.rendering``), so the test modules may import MuJoCo in any order."""
