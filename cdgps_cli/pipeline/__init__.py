"""Stage orchestration: the mapping from a RUN to its models, stage functions, and the batch layer
(architecture.md, "pipeline/")."""
