"""Reports and summaries written for people: HTML pages, figures, markdown (architecture.md, "report/")."""
