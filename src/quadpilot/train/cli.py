from quadpilot._stub import not_yet


def main(argv=None) -> int:
    return not_yet("quad-train", "the PPO issue")
