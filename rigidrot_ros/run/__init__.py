"""The run model, with no ROS: parameters, set-up, the table of outputs, schedule, generation.

``params`` (the one parameter table) and ``settings`` (values -> a validated run set-up);
``grid`` (every stream's stamps) and ``scheduler`` (sensor grids, timing models, the choice
of the next batch); ``table`` (the table of outputs: one kind per row, each in its own
module, ``truth_outputs``, ``imu_output``, ``star_output``, ``mag_output``, and ``outputs``
for the run description, all on the base classes of ``output``: topics, type, rank,
enabling parameter, reading a block of samples, encoding to CDR and to messages);
``schedule``, ``truth_ahead`` and ``sensor_ahead`` (the node's one timer: what each call
publishes, its samples read and encoded ahead); ``generate`` (a whole run into a bag
offline, byte-identical to the node's recording) and ``spans`` (its blocks as MCAP
records and chunks).
"""
