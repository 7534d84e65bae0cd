//! The docs book's column reference (`docs/src/tables.md`), rendered from the schemas in
//! [`crate::tables`], so the page cannot drift from what a run stores: a test renders it again and
//! fails when the committed page differs (`LIBERO_UPDATE_DOCS=1 cargo test -p libero-schema`
//! rewrites it).
//!
//! Types are written the way a reader meets them in polars or pyarrow, compactly:
//! `float64[3]` is a fixed-size list of 3, `list<int32>` a variable-length list,
//! `list<struct{name, pos, quat}>` a list of structs.

use crate::tables::{self, DOC_KEY, SPEC_COLUMNS, TABLES_VERSION};
use arrow_schema::{DataType, Field, Schema};
use std::fmt::Write;

/// The tables in the order the page lists them: (heading, where a run stores it, schema).
fn stored_tables() -> [(&'static str, &'static str, std::sync::Arc<Schema>); 4] {
    [
        ("steps", "`RUN/steps/*.parquet`, one row per env step of a LIBERO episode", tables::steps()),
        (
            "aloha_steps",
            "`RUN/steps/*.parquet` of an ALOHA-sim run (`manifest.env = aloha_sim`), one row per env step",
            tables::aloha_steps(),
        ),
        (
            "episodes",
            "`RUN/episodes/*.parquet`, one row per episode, then the spec table's extra columns",
            tables::episodes(),
        ),
        ("manifest", "`RUN/manifest.parquet` (and `manifest.json`), one row per run", tables::manifest()),
    ]
}

/// The Markdown page `docs/src/tables.md`.
pub fn tables_markdown() -> String {
    let mut md = String::new();
    md.push_str("# Tables and columns\n\n");
    md.push_str(
        "<!-- Generated from schema/src/tables.rs by schema/src/tables_reference.rs; do not edit. \
         Regenerate: LIBERO_UPDATE_DOCS=1 cargo test -p libero-schema -->\n\n",
    );
    let _ = writeln!(
        md,
        "The tables a run stores (layout version {TABLES_VERSION}), column by column. Every column's \
         text below is also in the Parquet files' field metadata (key `{DOC_KEY}`), so a notebook \
         sees it: `pyarrow.parquet.read_schema(path).field(name).metadata`. Types: `float64[3]` is \
         a fixed-size list of 3, `list<int32>` a list of any length; \"null\" says the column may be null.\n"
    );
    md.push_str("## specs\n\n");
    md.push_str(
        "`RUN/specs.parquet`: the spec table the run was started with, one row per episode. These \
         columns are required. An optional `protocol` column (string, one value per table: \
         `canonical` when absent or null, or `lerobot`) says which published loop the rows \
         reproduce, how the env was seeded and so which fixture poses an episode starts from \
         (see [Protocol](protocol.md)); it is stored in the episodes' `protocol`. Every other column \
         is carried through to the episode rows, and the perturbation columns perturb the episode \
         (see [LIBERO-Plus](libero-plus.md) and [LIBERO-PRO](libero-pro.md)).\n\n",
    );
    md.push_str("| column | type |\n|---|---|\n");
    for (name, data_type) in &SPEC_COLUMNS {
        let _ = writeln!(md, "| `{name}` | {} |", type_name(data_type));
    }
    for (name, stored, schema) in stored_tables() {
        let _ = write!(md, "\n## {name}\n\n{stored}.\n\n| column | type | meaning |\n|---|---|---|\n");
        for field in schema.fields() {
            let _ = writeln!(md, "| `{}` | {} | {} |", field.name(), field_type(field), doc(field));
        }
    }
    md
}

fn field_type(field: &Field) -> String {
    let t = type_name(field.data_type());
    if field.is_nullable() { format!("{t}, null") } else { t }
}

/// A field's documentation, made safe for one Markdown table cell.
fn doc(field: &Field) -> String {
    field.metadata().get(DOC_KEY).map(String::as_str).unwrap_or("").replace('|', "\\|").replace('\n', " ")
}

fn type_name(data_type: &DataType) -> String {
    match data_type {
        DataType::Boolean => "bool".into(),
        DataType::Int32 => "int32".into(),
        DataType::Int64 => "int64".into(),
        DataType::UInt32 => "uint32".into(),
        DataType::Float32 => "float32".into(),
        DataType::Float64 => "float64".into(),
        DataType::Utf8 => "string".into(),
        DataType::FixedSizeList(item, n) => format!("{}[{n}]", type_name(item.data_type())),
        DataType::List(item) => format!("list<{}>", type_name(item.data_type())),
        DataType::Struct(fields) => {
            let names: Vec<&str> = fields.iter().map(|f| f.name().as_str()).collect();
            format!("struct{{{}}}", names.join(", "))
        }
        other => format!("{other}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    /// The committed page equals what the schemas render; `LIBERO_UPDATE_DOCS=1` rewrites it.
    #[test]
    fn the_books_column_reference_matches_the_schemas() {
        let page = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/src/tables.md");
        let rendered = tables_markdown();
        if std::env::var_os("LIBERO_UPDATE_DOCS").is_some() {
            std::fs::write(&page, &rendered).unwrap();
        }
        let committed = std::fs::read_to_string(&page).unwrap_or_else(|e| {
            panic!("{}: {e}; write it with LIBERO_UPDATE_DOCS=1 cargo test -p libero-schema", page.display())
        });
        assert!(
            committed == rendered,
            "{} differs from the schemas in schema/src/tables.rs: regenerate it with \
             `LIBERO_UPDATE_DOCS=1 cargo test -p libero-schema` and commit the page",
            page.display()
        );
    }

    #[test]
    fn every_column_of_every_table_is_on_the_page() {
        let page = tables_markdown();
        for (_, _, schema) in stored_tables() {
            for field in schema.fields() {
                assert!(page.contains(&format!("| `{}` |", field.name())), "{} missing", field.name());
            }
        }
        assert_eq!(type_name(&tables::fixed_list(DataType::Float64, 3)), "float64[3]");
        assert_eq!(type_name(&tables::list(DataType::Int32)), "list<int32>");
    }
}
