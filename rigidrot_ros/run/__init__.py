"""The run model, with no ROS: parameters, scene set-up, the output table, streams, generation.

``params`` (the one parameter table) and ``settings`` (values -> a validated run set-up),
``grid`` (every stream's stamps on one grid) and ``scheduler`` (which samples a tick is due),
``outputs`` (the table of outputs: topic, type, rank, enabling parameter), ``streams`` and
``sensor_ahead`` (blocks of samples, truth and sensors, ahead of their stamps), and
``generate`` (a whole run into a bag offline, byte-identical to the node's recording).
"""
