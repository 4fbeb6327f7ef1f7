"""Helpers that test_node_processes.py shares with other test modules."""

import textwrap


SUBSCRIBER = textwrap.dedent('''
    import json, sys, time
    import rclpy
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    rclpy.init()
    node = rclpy.create_node('estimator')
    got = {'attitude': [], 'angular_velocity': []}
    node.create_subscription(QuaternionStamped, sys.argv[1] + '/attitude',
        lambda m: got['attitude'].append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
        100)
    node.create_subscription(Vector3Stamped, sys.argv[1] + '/angular_velocity',
        lambda m: got['angular_velocity'].append(
            m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), 100)
    end = None
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if got['attitude'] and end is None:
            end = time.monotonic() + float(sys.argv[2])
        if end is not None and time.monotonic() > end:
            break
    print(json.dumps(got))
''')


CLIENT = textwrap.dedent('''
    import json, sys
    import rclpy
    from rcl_interfaces.srv import SetParametersAtomically
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger
    rclpy.init()
    node = rclpy.create_node('client')
    target = sys.argv[1]
    out = {}
    setp = node.create_client(SetParametersAtomically, target + '/set_parameters_atomically')
    assert setp.wait_for_service(timeout_sec=20)
    for label, params in json.loads(sys.argv[2]):
        req = SetParametersAtomically.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in params.items()]
        fut = setp.call_async(req)
        rclpy.spin_until_future_complete(node, fut, timeout_sec=20)
        r = fut.result().result
        out[label] = [r.successful, r.reason]
    reset = node.create_client(Trigger, target + '/reset')
    assert reset.wait_for_service(timeout_sec=20)
    fut = reset.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(node, fut, timeout_sec=20)
    out['reset'] = [fut.result().success, fut.result().message]
    print(json.dumps(out))
''')
