//! The engine over a journal that fails: a storage fault, a duplicate index and an
//! unreadable entry each reach the job as their own [`JournalError`], with the messages
//! the daemon stores.

use serde_json::json;

use super::engine::{self, CampaignError, Retry, Step, StepError};
use crate::procedures::{EntryStatus, Journal, JournalEntry, JournalError, MemoryJournal};
use crate::run::JobError;
use crate::util::{Monitor, NoMonitor};

/// A step that measures its plan entry as is.
struct Echo;

impl Step for Echo {
    type Plan = f64;
    type Sample = f64;
    const STAGE: &'static str = "echo";

    fn describe(&self, k: usize, n: usize, _: &f64) -> String {
        format!("{k} of {n}")
    }

    fn measure(
        &self,
        _: usize,
        plan: &f64,
        _: &dyn Monitor,
    ) -> impl std::future::Future<Output = Result<f64, StepError>> + Send {
        let v = *plan;
        async move { Ok(v) }
    }
}

fn run(journal: &dyn Journal, plan: &[f64]) -> Result<engine::Summary, CampaignError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(engine::run(
        &Echo,
        plan,
        0,
        journal,
        &Retry::default(),
        &NoMonitor,
    ))
}

#[test]
fn a_journal_storage_fault_stops_the_campaign_as_a_typed_journal_error() {
    let journal = MemoryJournal::failing_after(2);
    let e = run(&journal, &[1.0, 2.0, 3.0, 4.0]).expect_err("the third append fails");
    assert_eq!(
        e,
        CampaignError::Journal(JournalError::Storage {
            message: "journal storage failed".into()
        })
    );
    // The two measurements before the fault stay journalled.
    let kept: Vec<f64> = engine::recorded(&journal, 0, 4).expect("readable");
    assert_eq!(kept, vec![1.0, 2.0]);
    let job = JobError::from(e);
    assert!(job.is_internal(), "{job:?}");
    assert_eq!(
        job.to_string(),
        "the measurement journal failed: journal storage failed; nothing more is measured"
    );
}

#[test]
fn a_duplicate_index_is_refused_by_index_and_not_a_storage_fault() {
    let journal = MemoryJournal::default();
    let entry = |v: f64| JournalEntry {
        index: 7,
        status: EntryStatus::Measured,
        data: json!(v),
    };
    journal.append(&entry(1.0)).expect("first");
    let e = journal.append(&entry(2.0)).expect_err("second");
    assert_eq!(e, JournalError::Duplicate { index: 7 });
    assert_eq!(e.to_string(), "configuration 7 is already in the journal");
    let job = JobError::from(e);
    assert!(!job.is_internal());
    assert_eq!(
        job.to_string(),
        "the measurement journal failed: configuration 7 is already in the journal; \
         nothing more is measured"
    );
}

#[test]
fn an_unreadable_entry_is_named_by_its_index() {
    let entries = vec![
        JournalEntry {
            index: 0,
            status: EntryStatus::Measured,
            data: json!(0.5),
        },
        JournalEntry {
            index: 1,
            status: EntryStatus::Measured,
            data: json!({"edited": "by hand"}),
        },
    ];
    let journal = MemoryJournal::with(entries);
    let e = engine::recorded::<f64>(&journal, 0, 2).expect_err("entry 1 is not a number");
    let JobError::Journal(JournalError::Unreadable { index, message }) = &e else {
        panic!("{e:?}");
    };
    assert_eq!(*index, 1);
    assert!(message.contains("expected f64"), "{message}");
    assert!(!e.is_internal());
    assert!(
        e.to_string().starts_with("journal entry 1 is unreadable: "),
        "{e}"
    );
    // Outside the range asked for, the same entry is not read.
    assert_eq!(
        engine::recorded::<f64>(&journal, 0, 1).expect("entry 0"),
        vec![0.5]
    );
}
