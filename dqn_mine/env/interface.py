"""What an agent sees and does: the frame's shape and the six actions, defined once.

Kept free of imports so that the replay, the network and the exploration code can share these
numbers without loading the renderer.
"""

OBS_HEIGHT, OBS_WIDTH = 44, 76
FRAME_SHAPE = (3, OBS_HEIGHT, OBS_WIDTH)   # one RGB frame, channels first

FORWARD, BACKWARD, TURN_RIGHT, TURN_LEFT, INTERACT, NOOP = range(6)
ACTION_NAMES = ("forward", "backward", "turn right", "turn left", "pick/drop/exchange/deliver",
                "no-op")
NUM_ACTIONS = len(ACTION_NAMES)
