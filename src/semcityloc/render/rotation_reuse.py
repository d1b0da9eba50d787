"""stub"""


def render_yaw_fan(*a, **k):
    raise NotImplementedError
