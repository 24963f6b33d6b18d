"""Log writers: the simulator writes every format the ingest stage reads."""
