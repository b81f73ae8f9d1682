//! What the daemon makes of each kind of job error: the HTTP status, code and message of a
//! refused submission, the message a failed job stores, and which failures it logs as its
//! own (internal) faults.

use axum::http::StatusCode;

use super::ServiceError;
use crate::api::ApiError;
use crate::lab::LabError;
use crate::procedures::{CentringError, DeviceError, JournalError};
use crate::run::JobError;

/// Status, error code and body message of a submission refused with `e`.
fn refused(e: JobError) -> (StatusCode, &'static str, String) {
    let api = ApiError::from(ServiceError::from(e));
    let (status, code) = api.status();
    (status, code, api.to_string())
}

fn disconnected() -> DeviceError {
    DeviceError::Disconnected {
        device: "robot".into(),
    }
}

#[test]
fn the_jobs_own_faults_are_422_with_their_message() {
    let e = JobError::invalid("options.noise", "-1 must be positive");
    assert_eq!(
        refused(e),
        (
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid",
            "`options.noise`: -1 must be positive".to_string()
        )
    );
    // A cell the lab does not have is the job's fault; another lab fault is not.
    let no_cell = JobError::from(LabError::NoCell {
        name: "irb9".into(),
        what: "ball-centring cell",
        have: vec!["irb120".into()],
    });
    assert_eq!(
        refused(no_cell),
        (
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid",
            "`cell`: no ball-centring cell `irb9` in this lab (it has: irb120)".to_string()
        )
    );
    let lab = JobError::from(LabError::DuplicateCell("irb120".into()));
    assert!(matches!(lab, JobError::Lab(_)), "{lab:?}");
    assert_eq!(lab.to_string(), "two cells are named `irb120`");
    assert_eq!(
        refused(lab),
        (
            StatusCode::INTERNAL_SERVER_ERROR,
            "internal",
            "internal error".into()
        )
    );
}

#[test]
fn every_other_fault_is_500_without_its_details() {
    let faults = [
        JobError::internal("a computation panicked", "task 3 panicked"),
        JobError::io(
            "writing the main table",
            Some(std::path::Path::new("/srv/spool/job-4-1.csv")),
            std::io::Error::other("no space left"),
        ),
        JobError::Journal(JournalError::storage("store: database: disk I/O error")),
        JobError::Device(disconnected()),
        JobError::Upload {
            cell: "irb120".into(),
            message: "RAPID program is executing".into(),
        },
        JobError::CellMismatch {
            what: "plate",
            message: "the plate has no ball 4".into(),
        },
    ];
    for e in faults {
        let shown = e.to_string();
        let (status, code, message) = refused(e);
        assert_eq!(
            (status, code),
            (StatusCode::INTERNAL_SERVER_ERROR, "internal")
        );
        assert_eq!(message, "internal error", "{shown} leaked");
    }
}

#[test]
fn failed_jobs_keep_their_messages_and_only_calibds_faults_are_internal() {
    // (error, the message the job stores, logged as calibd's own fault)
    let cases = [
        (
            JobError::internal("a computation panicked", "task 3 panicked"),
            "internal error: a computation panicked: task 3 panicked",
            true,
        ),
        (
            JobError::io(
                "cannot create the spool folder",
                Some(std::path::Path::new("/srv/spool")),
                std::io::Error::other("read-only file system"),
            ),
            "cannot create the spool folder /srv/spool: read-only file system",
            true,
        ),
        (
            JobError::io(
                "writing the poses CSV",
                None,
                std::io::Error::other("broken pipe"),
            ),
            "writing the poses CSV: broken pipe",
            true,
        ),
        (
            JobError::Journal(JournalError::storage("journal storage failed")),
            "the measurement journal failed: journal storage failed; nothing more is measured",
            true,
        ),
        (
            JobError::Journal(JournalError::Unreadable {
                index: 4,
                message: "invalid type: string \"x\", expected f64".into(),
            }),
            "journal entry 4 is unreadable: invalid type: string \"x\", expected f64",
            false,
        ),
        (
            JobError::Device(disconnected()),
            "robot: disconnected",
            false,
        ),
        (
            JobError::Procedure {
                procedure: "centring aborted",
                source: CentringError::Device(disconnected()),
            },
            "centring aborted: device: robot: disconnected",
            false,
        ),
        (
            JobError::Procedure {
                procedure: "jog",
                source: CentringError::Device(disconnected()),
            },
            "jog: device: robot: disconnected",
            false,
        ),
        (
            JobError::Upload {
                cell: "irb120".into(),
                message: "RAPID program is executing".into(),
            },
            "upload to cell irb120: RAPID program is executing",
            false,
        ),
        (
            JobError::CellMismatch {
                what: "model",
                message:
                    "commissioning needs a model with lengths in mm (the cell's model is in m)"
                        .into(),
            },
            "commissioning needs a model with lengths in mm (the cell's model is in m)",
            false,
        ),
    ];
    for (e, message, internal) in cases {
        assert_eq!(e.to_string(), message);
        assert_eq!(e.is_internal(), internal, "{message}");
        assert!(!e.is_invalid_input(), "{message}");
    }
}
