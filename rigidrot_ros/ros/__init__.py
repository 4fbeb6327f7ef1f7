"""The ROS 2 layer: the attitude node, its parameters, spinning, and recording from topics.

``attitude_node`` (the node's wiring), ``cli`` (its console script), ``ros_params``
(the parameter table declared to rclpy), ``spin`` (signals and shutdown), ``recording``
(the node's recorder set-up) and ``recorder`` (the recording component of the node and
of ``rigidrot_record``). Everything rclpy-dependent lives here, or in a thin ``main``.
"""
