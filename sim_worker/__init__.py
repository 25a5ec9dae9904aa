"""The PyBullet world, the scripted teacher, the control loop and the Zenoh worker side."""
