"""The job state machine: rounds, commits, resume. Receives a JobStore, an ArtifactStore and an
Executor; never imports Ray or FastAPI (ARCHITECTURE §2)."""
