"""What real parts add to an idealised device: flicker noise, sample clocks with jitter
and drift, converter errors, sensor lag and actuator hysteresis.

ROS-free numerical models, each with its parameter table (unit, range, source, spread)
and closed-form checks; the device models compose them, and a device's ``ideal``
hardware profile switches every term off.
"""
