"""What a real robot needs, and nothing of the simulator: never gymnasium, and GL only when asked.

An offscreen GL context is created only for the outline stage's contours (``contours``), at their first use.

``model`` (the robot from its MJCF or URDF: kinematics and geometry), ``tracking`` (keypoint tracks),
``recording`` (the recording format), ``session`` (the one calibration loop), ``driver`` (the
``RobotDriver`` protocol), ``exports`` (result.json and ROS exports; the atomic writer), ``overlay``
(the robot drawn over frames with an estimate), ``timing`` (joints at exposure times: the time
offset), ``segmentation`` (exploratory motions in a joint stream), ``bag`` (ROS bags in and out),
``motion_script`` (exploratory motions out, as a timed joint trajectory), ``obstacles`` (boxes and spheres
a script keeps clear of).
"""
