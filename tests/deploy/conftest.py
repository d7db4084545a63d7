from s3_server import s3_server  # noqa: F401  (fixture)
