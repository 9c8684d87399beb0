use std::collections::BTreeSet;

use super::*;

/// api/openapi.yaml is what the code generates: regenerate it after changing the API.
#[test]
fn the_checked_in_document_is_the_generated_one() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/api/openapi.yaml");
    let checked_in = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        checked_in == document(),
        "api/openapi.yaml differs from the document the code generates; regenerate it with \
         `cargo run -- openapi -o api/openapi.yaml`"
    );
}

/// Every (method, path) the router serves is documented, and every documented operation is
/// served. Paths are compared in the OpenAPI form (`{id}`), which the router uses too.
#[test]
fn the_document_matches_the_router() {
    let document = ApiDoc::openapi();
    let mut documented = BTreeSet::new();
    for (path, item) in &document.paths.paths {
        for (method, operation) in [
            ("GET", &item.get),
            ("POST", &item.post),
            ("PUT", &item.put),
            ("PATCH", &item.patch),
            ("DELETE", &item.delete),
        ] {
            if operation.is_some() {
                documented.insert((method.to_owned(), path.clone()));
            }
        }
    }
    let served: BTreeSet<_> = super::super::endpoints()
        .iter()
        .map(|endpoint| (endpoint.method.to_string(), endpoint.path.to_owned()))
        .collect();
    assert_eq!(
        served.difference(&documented).collect::<Vec<_>>(),
        Vec::<&(String, String)>::new(),
        "served but not documented"
    );
    assert_eq!(
        documented.difference(&served).collect::<Vec<_>>(),
        Vec::<&(String, String)>::new(),
        "documented but not served"
    );
}
