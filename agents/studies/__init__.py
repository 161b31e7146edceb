"""The studies and analyses of ``quadslam study …``."""
