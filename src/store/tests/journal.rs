//! The store's journal tells a duplicate index from a storage fault: the campaign engine
//! stops on both, but only the second is the store's (or the host's) fault.

use serde_json::json;

use super::{Fixture, job};
use crate::procedures::{EntryStatus, Journal, JournalEntry, JournalError};
use crate::store::StoreJournal;

fn entry(index: usize) -> JournalEntry {
    JournalEntry {
        index,
        status: EntryStatus::Measured,
        data: json!({"q": [index]}),
    }
}

fn a_duplicate_index_and_a_refused_write_are_told_apart(f: &Fixture) {
    let store = f.open();
    let (id, _) = store.insert_job_once(&job("cell.trical_campaign")).unwrap();
    let journal = StoreJournal {
        store: store.clone(),
        job: id,
    };
    journal.append(&entry(0)).unwrap();
    journal.append(&entry(1)).unwrap();
    assert_eq!(
        journal.append(&entry(1)),
        Err(JournalError::Duplicate { index: 1 })
    );
    // A journal of a job the store does not hold: the database refuses the row (foreign
    // key), a storage fault that names the store, never a duplicate.
    let orphan = StoreJournal {
        store: store.clone(),
        job: id + 1000,
    };
    match orphan.append(&entry(1)) {
        Err(JournalError::Storage { message }) => {
            assert!(message.starts_with("store: "), "{message}")
        }
        other => panic!("{other:?}"),
    }
    let kept = journal.entries().unwrap();
    assert_eq!(kept.iter().map(|e| e.index).collect::<Vec<_>>(), vec![0, 1]);
    assert_eq!(kept[1], entry(1));
}

#[test]
fn sqlite_a_duplicate_index_and_a_refused_write_are_told_apart() {
    a_duplicate_index_and_a_refused_write_are_told_apart(&Fixture::sqlite());
}

#[test]
fn postgres_a_duplicate_index_and_a_refused_write_are_told_apart() {
    if let Some(f) = Fixture::postgres() {
        a_duplicate_index_and_a_refused_write_are_told_apart(&f);
    }
}

/// A journal whose database loses its table under it (another program damaged the file):
/// the next append fails in SQLite, a typed storage fault that names the store.
#[test]
fn a_journal_write_into_a_damaged_database_is_a_storage_fault() {
    let dir = tempfile::tempdir().unwrap();
    let store = crate::store::Store::open(dir.path()).unwrap();
    let (id, _) = store.insert_job_once(&job("cell.trical_campaign")).unwrap();
    let journal = StoreJournal { store, job: id };
    journal.append(&entry(0)).unwrap();
    rusqlite::Connection::open(dir.path().join("calibd.sqlite3"))
        .unwrap()
        .execute_batch("DROP TABLE measurements")
        .unwrap();
    let e = journal.append(&entry(1)).expect_err("the table is gone");
    let JournalError::Storage { message } = &e else {
        panic!("{e:?}");
    };
    assert!(
        message.starts_with("store: database: ") && message.contains("measurements"),
        "{message}"
    );
    assert!(matches!(
        journal.entries(),
        Err(JournalError::Storage { .. })
    ));
}
