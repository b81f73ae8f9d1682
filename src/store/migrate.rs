//! Schema migrations: an ordered list of SQL steps, applied in one transaction at start-up
//! by each backend (SQLite as written, PostgreSQL translated; a database newer than this
//! binary is refused).

/// The schema steps, oldest first. Never edit a released step: append a new one.
const STEPS: &[&str] = &[
    // 1: jobs, their inputs (datasets), progress history, results, artefacts, logs, schedules.
    "CREATE TABLE jobs (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        kind TEXT NOT NULL,
        state TEXT NOT NULL,
        priority INTEGER NOT NULL DEFAULT 0,
        devices TEXT NOT NULL DEFAULT '[]',
        doc TEXT NOT NULL,
        inputs_sha256 TEXT NOT NULL DEFAULT '{}',
        submitted_at TEXT NOT NULL,
        started_at TEXT,
        finished_at TEXT,
        progress REAL NOT NULL DEFAULT 0,
        stage TEXT,
        message TEXT,
        error TEXT,
        submitted_by TEXT,
        schedule_id INTEGER,
        rerun_of INTEGER
    );
    CREATE INDEX jobs_state ON jobs(state, id);
    CREATE INDEX jobs_kind ON jobs(kind, id);
    CREATE TABLE datasets (
        id TEXT PRIMARY KEY,
        name TEXT NOT NULL,
        media_type TEXT NOT NULL,
        size INTEGER NOT NULL,
        created_at TEXT NOT NULL,
        content BLOB NOT NULL
    );
    CREATE TABLE progress (
        job_id INTEGER NOT NULL REFERENCES jobs(id),
        at TEXT NOT NULL,
        fraction REAL NOT NULL,
        stage TEXT NOT NULL,
        message TEXT
    );
    CREATE INDEX progress_job ON progress(job_id);
    CREATE TABLE results (
        job_id INTEGER PRIMARY KEY REFERENCES jobs(id),
        result TEXT NOT NULL,
        main_table_csv TEXT
    );
    CREATE TABLE artefacts (
        job_id INTEGER NOT NULL REFERENCES jobs(id),
        name TEXT NOT NULL,
        media_type TEXT NOT NULL,
        content BLOB NOT NULL,
        PRIMARY KEY (job_id, name)
    );
    CREATE TABLE logs (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        job_id INTEGER,
        at TEXT NOT NULL,
        level TEXT NOT NULL,
        message TEXT NOT NULL
    );
    CREATE INDEX logs_job ON logs(job_id, id);
    CREATE TABLE schedules (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        name TEXT NOT NULL UNIQUE,
        cron TEXT NOT NULL,
        timezone TEXT NOT NULL,
        job TEXT NOT NULL,
        priority INTEGER NOT NULL DEFAULT 0,
        missed TEXT NOT NULL,
        enabled INTEGER NOT NULL DEFAULT 1,
        created_at TEXT NOT NULL,
        created_by TEXT,
        checked_until TEXT NOT NULL
    );
    CREATE TABLE schedule_runs (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        schedule_id INTEGER NOT NULL,
        due_at TEXT NOT NULL,
        at TEXT NOT NULL,
        outcome TEXT NOT NULL,
        job_id INTEGER,
        message TEXT
    );
    CREATE INDEX schedule_runs_schedule ON schedule_runs(schedule_id, id);",
    // 2: campaign measurement journals and the cells' model history.
    "CREATE TABLE measurements (
        job_id INTEGER NOT NULL REFERENCES jobs(id),
        idx INTEGER NOT NULL,
        status TEXT NOT NULL,
        data TEXT NOT NULL,
        at TEXT NOT NULL,
        PRIMARY KEY (job_id, idx)
    );
    CREATE TABLE cell_models (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        cell TEXT NOT NULL,
        job_id INTEGER,
        state TEXT NOT NULL,
        reason TEXT NOT NULL,
        validation TEXT NOT NULL,
        model TEXT NOT NULL,
        at TEXT NOT NULL
    );
    CREATE INDEX cell_models_cell ON cell_models(cell, id);",
    // Idempotent submission: the key a client sent with a job, per token name, and the
    // hash of what it submitted; written in the job's own transaction.
    "CREATE TABLE idempotency_keys (
        submitted_by TEXT NOT NULL,
        key TEXT NOT NULL,
        request_sha256 TEXT NOT NULL,
        job_id INTEGER NOT NULL REFERENCES jobs(id),
        at TEXT NOT NULL,
        PRIMARY KEY (submitted_by, key)
    );",
    // 4: a job's run token: `attempt` counts its starts (claims), and a run writes its result,
    // progress and end state only while the job is still its attempt; an operator's cancel
    // of a job that runs on another daemon of a fleet is a flag that daemon reads.
    "ALTER TABLE jobs ADD COLUMN attempt INTEGER NOT NULL DEFAULT 0;
    ALTER TABLE jobs ADD COLUMN cancel_requested INTEGER NOT NULL DEFAULT 0;",
    // 5: when a paused or interrupted job was last resumed (`started_at` keeps its first start).
    "ALTER TABLE jobs ADD COLUMN resumed_at TEXT;",
];

/// The schema steps (shared with the PostgreSQL backend, which translates them).
pub(crate) fn steps() -> &'static [&'static str] {
    STEPS
}

/// The schema version this binary writes.
pub const SCHEMA_VERSION: i64 = STEPS.len() as i64;
