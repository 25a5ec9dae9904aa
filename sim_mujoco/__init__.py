"""The cell in MuJoCo beside PyBullet (issue 44): the model, the contact truth and the wrist sensor, ``MujocoRobot``."""
