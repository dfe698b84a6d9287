"""Ingest of standard ROS sensor messages and device protocols into the project's measurements.

What a train's own drivers publish (sensor_msgs/NavSatFix, sensor_msgs/Imu, nav_msgs/Odometry,
geometry_msgs/TwistWithCovarianceStamped) becomes the decoded measurements the fusion
consumes (core/measurements.py), through the same map matching and error models as the
project's own sensors (docs/integration.md, "From your drivers"):

  records.py   typed records of the standard messages, admitted (NaN, ranges, covariances)
  navsat.py    a GNSS fix -> a DGPS PositionFix (map-matched by core/sensors/dgps.py)
  imu.py       IMU samples -> the gyro's YawRate and the accelerometer's Acceleration (their decoders)
  speed.py     a body twist -> a Doppler SpeedMeasurement or a wheel DistanceIncrement
  inputs.py    the configuration of every input and the models they are floored by

and what devices without a ROS driver send becomes those standard messages' records:

  nmea.py      NMEA 0183 sentences (GGA, GST, RMC, VTG; pynmea2) -> GNSS fixes with their accuracy
  canbus.py    CAN frames of a wheel pulse generator and a radar (cantools, a DBC) -> body speeds
  streams.py   the lines of a file, a UDP port or a serial device
  pacing.py    the pace of a recording replayed into a live graph
"""
