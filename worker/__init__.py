"""RQ workers of the MoJu service: the job function and the worker process that runs it."""
