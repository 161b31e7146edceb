"""The studies (``quadslam study …``) and the analyses run as
``python -m agents.studies.<name>``."""
