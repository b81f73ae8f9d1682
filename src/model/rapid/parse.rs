//! The RAPID module parser: checks the block structure (MODULE, routines, IF/FOR/WHILE/TEST,
//! RECORD), that every statement ends with `;` and that brackets match, and collects the
//! data declarations (with their literal values and byte spans) and the move instructions
//! that use robtargets (with their tool and work object). Errors name the line.

use super::RapidError;
use super::lex::{Tok, Token, tokens};

/// A value of a declaration: a number, a bracketed list, a word or another expression.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A numeric literal with its sign; `start..end` spans sign and digits.
    Num {
        /// The value.
        v: f64,
        /// First byte.
        start: usize,
        /// One past the last byte.
        end: usize,
    },
    /// `[a, b, ...]`.
    List {
        /// The items.
        items: Vec<Value>,
        /// Byte of `[`.
        start: usize,
        /// One past `]`.
        end: usize,
    },
    /// A name, a boolean or a string.
    Word(String),
    /// Any other expression (not a literal calibd can rewrite).
    Expr,
}

impl Value {
    /// The numbers of a flat list of `n` numbers.
    pub fn numbers(&self, n: usize) -> Option<Vec<(f64, usize, usize)>> {
        let Value::List { items, .. } = self else {
            return None;
        };
        if items.len() != n {
            return None;
        }
        items
            .iter()
            .map(|v| match v {
                Value::Num { v, start, end } => Some((*v, *start, *end)),
                _ => None,
            })
            .collect()
    }

    /// The items of a list.
    pub fn items(&self) -> Option<&[Value]> {
        match self {
            Value::List { items, .. } => Some(items),
            _ => None,
        }
    }
}

/// A data declaration: `[LOCAL|TASK] CONST|PERS|VAR type name[{dims}] [:= value];`.
#[derive(Debug, Clone, PartialEq)]
pub struct Decl {
    /// Line of the declaration's first token.
    pub line: usize,
    /// `CONST`, `PERS` or `VAR`, as written.
    pub storage: String,
    /// Data type, lower case (`robtarget`, `tooldata`, ...).
    pub ty: String,
    /// Name as written.
    pub name: String,
    /// Array dimensions (empty for a scalar); `None` entries are not literal numbers.
    pub dims: Vec<Option<usize>>,
    /// The initial value, if any.
    pub value: Option<Value>,
    /// Byte of the first token.
    pub start: usize,
    /// One past the `;`.
    pub end: usize,
    /// Bytes of the type name.
    pub ty_span: (usize, usize),
    /// Bytes of the data name.
    pub name_span: (usize, usize),
    /// Bytes of the value after `:=`.
    pub value_span: Option<(usize, usize)>,
    /// The routine it is declared in (`None` at module level).
    pub routine: Option<String>,
}

/// A move instruction and the robtargets it uses.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveUse {
    /// Line of the instruction.
    pub line: usize,
    /// Instruction name as written (`MoveL`).
    pub instruction: String,
    /// Robtarget names it moves to, each with whether it goes through `Offs` / `RelTool`.
    pub targets: Vec<(String, bool)>,
    /// The tool argument's name.
    pub tool: Option<String>,
    /// The `\WObj` argument's name (`None`: wobj0).
    pub wobj: Option<String>,
}

/// A parsed module.
#[derive(Debug, Clone, PartialEq)]
pub struct Module {
    /// The module name.
    pub name: String,
    /// Every data declaration, module level and local to routines, in text order.
    pub decls: Vec<Decl>,
    /// Every move instruction that uses robtargets.
    pub moves: Vec<MoveUse>,
}

/// Move instructions: (name, indices of robtarget arguments, index of the tool) among the
/// required arguments.
const MOVES: &[(&str, &[usize], usize)] = &[
    ("MoveL", &[0], 3),
    ("MoveJ", &[0], 3),
    ("MoveLDO", &[0], 3),
    ("MoveJDO", &[0], 3),
    ("MoveLSync", &[0], 3),
    ("MoveJSync", &[0], 3),
    ("MoveLAO", &[0], 3),
    ("MoveJAO", &[0], 3),
    ("MoveLGO", &[0], 3),
    ("MoveJGO", &[0], 3),
    ("MoveC", &[0, 1], 4),
    ("MoveCDO", &[0, 1], 4),
    ("MoveCSync", &[0, 1], 4),
    ("MoveCAO", &[0, 1], 4),
    ("MoveCGO", &[0, 1], 4),
    ("TriggL", &[0], 4),
    ("TriggJ", &[0], 4),
    ("TriggC", &[0, 1], 5),
    ("SearchL", &[2], 4),
    ("SearchC", &[2, 3], 5),
];

/// Keywords that close or continue a block: a statement running into one lacks its `;`.
const BLOCK_WORDS: &[&str] = &[
    "MODULE",
    "ENDMODULE",
    "PROC",
    "ENDPROC",
    "FUNC",
    "ENDFUNC",
    "TRAP",
    "ENDTRAP",
    "RECORD",
    "ENDRECORD",
    "ENDIF",
    "ELSE",
    "ELSEIF",
    "ENDFOR",
    "ENDWHILE",
    "ENDTEST",
    "CASE",
    "DEFAULT",
    "CONST",
    "PERS",
    "VAR",
    "LOCAL",
];

/// Words that join two operands in an expression (`a DIV b`, `CONNECT i WITH t`).
const OPERATOR_WORDS: &[&str] = &["AND", "OR", "XOR", "NOT", "DIV", "MOD", "WITH"];

/// Parse a module text.
pub fn parse(src: &str) -> Result<Module, RapidError> {
    let toks = tokens(src)?;
    Parser {
        src,
        t: &toks,
        i: 0,
        blocks: Vec::new(),
        routine: None,
        decls: Vec::new(),
        moves: Vec::new(),
    }
    .module()
}

struct Parser<'a> {
    src: &'a str,
    t: &'a [Token],
    i: usize,
    /// Open blocks: keyword and line.
    blocks: Vec<(&'static str, usize)>,
    routine: Option<String>,
    decls: Vec<Decl>,
    moves: Vec<MoveUse>,
}

impl Parser<'_> {
    fn text(&self, k: usize) -> &str {
        self.t[k].text(self.src)
    }

    fn is(&self, k: usize, kw: &str) -> bool {
        self.t.get(k).is_some_and(|t| t.is(self.src, kw))
    }

    fn is_punct(&self, k: usize, p: &str) -> bool {
        self.t.get(k).is_some_and(|t| t.is_punct(self.src, p))
    }

    fn line(&self, k: usize) -> usize {
        self.t.get(k).or(self.t.last()).map_or(1, |t| t.line)
    }

    fn err(&self, k: usize, m: impl Into<String>) -> RapidError {
        RapidError::new(self.line(k), m)
    }

    fn ident(&self, k: usize, what: &str) -> Result<String, RapidError> {
        match self.t.get(k) {
            Some(t) if t.kind == Tok::Ident => Ok(self.text(k).to_string()),
            Some(_) => Err(self.err(k, format!("expected {what}, found `{}`", self.text(k)))),
            None => Err(self.err(k, format!("expected {what}, the file ends"))),
        }
    }

    fn module(mut self) -> Result<Module, RapidError> {
        if self.t.is_empty() {
            return Err(RapidError::new(1, "no MODULE: the file is empty"));
        }
        if !self.is(0, "MODULE") {
            return Err(self.err(0, format!("expected MODULE, found `{}`", self.text(0))));
        }
        let name = self.ident(1, "the module name")?;
        self.i = 2;
        if self.is_punct(2, "(") {
            self.i = self.close(2)? + 1;
        }
        self.blocks.push(("MODULE", self.t[0].line));
        while self.i < self.t.len() {
            if self.blocks.is_empty() {
                return Err(self.err(self.i, format!("`{}` after ENDMODULE", self.text(self.i))));
            }
            self.step()?;
        }
        if let Some((kw, line)) = self.blocks.last() {
            return Err(RapidError::new(
                *line,
                format!("{kw} is not closed (the file ends without its END{kw})"),
            ));
        }
        Ok(Module {
            name,
            decls: self.decls,
            moves: self.moves,
        })
    }

    /// One statement or block keyword at `self.i`.
    fn step(&mut self) -> Result<(), RapidError> {
        let i = self.i;
        let t = self.t[i];
        if t.kind != Tok::Ident {
            return self.statement();
        }
        let up = self.text(i).to_ascii_uppercase();
        match up.as_str() {
            "ENDMODULE" => self.close_block(i, "MODULE"),
            "PROC" | "TRAP" | "FUNC" | "RECORD" => {
                if let Some((kw, line)) = self.blocks.last().filter(|b| b.0 != "MODULE") {
                    return Err(self.err(
                        i,
                        format!("{up} inside the {kw} opened on line {line} (missing END{kw}?)"),
                    ));
                }
                let mut k = i + 1;
                if up == "FUNC" {
                    self.ident(k, "the function's return type")?;
                    k += 1;
                }
                let name = self.ident(k, "a name")?;
                k += 1;
                if matches!(up.as_str(), "PROC" | "FUNC") {
                    if !self.is_punct(k, "(") {
                        return Err(self.err(k, format!("expected `(` after {up} {name}")));
                    }
                    k = self.close(k)? + 1;
                }
                self.blocks.push((keyword(&up), t.line));
                self.routine = Some(name);
                self.i = k;
                Ok(())
            }
            "ENDPROC" => self.close_block(i, "PROC"),
            "ENDFUNC" => self.close_block(i, "FUNC"),
            "ENDTRAP" => self.close_block(i, "TRAP"),
            "ENDRECORD" => self.close_block(i, "RECORD"),
            "IF" => match self.find(i + 1, &["THEN"], true)? {
                Some(k) => {
                    self.blocks.push(("IF", t.line));
                    self.i = k + 1;
                    Ok(())
                }
                None => self.statement(),
            },
            "ELSEIF" => {
                self.inside(i, "IF")?;
                let k = self.find(i + 1, &["THEN"], false)?.unwrap_or(i);
                self.i = k + 1;
                Ok(())
            }
            "ELSE" => {
                self.inside(i, "IF")?;
                self.i = i + 1;
                Ok(())
            }
            "ENDIF" => self.close_block(i, "IF"),
            "FOR" | "WHILE" => {
                let Some(k) = self.find(i + 1, &["DO"], false)? else {
                    return Err(self.err(i, format!("{up} without DO")));
                };
                self.blocks.push((keyword(&up), t.line));
                self.i = k + 1;
                Ok(())
            }
            "ENDFOR" => self.close_block(i, "FOR"),
            "ENDWHILE" => self.close_block(i, "WHILE"),
            "TEST" => {
                let mut k = i + 1;
                while k < self.t.len() && !self.is(k, "CASE") && !self.is(k, "DEFAULT") {
                    if self.is(k, "ENDTEST") || self.is_punct(k, ";") {
                        break;
                    }
                    k += 1;
                }
                self.blocks.push(("TEST", t.line));
                self.i = k;
                Ok(())
            }
            "CASE" | "DEFAULT" => {
                self.inside(i, "TEST")?;
                let mut k = i + 1;
                while k < self.t.len() && !self.is_punct(k, ":") {
                    if self.is_punct(k, ";") {
                        return Err(self.err(k, format!("{up} without `:`")));
                    }
                    k += 1;
                }
                self.i = k + 1;
                Ok(())
            }
            "ENDTEST" => self.close_block(i, "TEST"),
            "ERROR" | "UNDO" | "BACKWARD" if self.routine.is_some() => {
                self.i = i + 1;
                if up == "ERROR" && self.is_punct(i + 1, "(") {
                    self.i = self.close(i + 1)? + 1;
                }
                Ok(())
            }
            _ if self.is_punct(i + 1, ":") => {
                self.i = i + 2; // a label
                Ok(())
            }
            _ => self.statement(),
        }
    }

    /// A name, number or string that is not an operator word.
    fn operand(&self, k: usize) -> bool {
        let t = self.t[k];
        match t.kind {
            Tok::Num | Tok::Str => true,
            Tok::Ident => !OPERATOR_WORDS.iter().any(|w| t.is(self.src, w)),
            Tok::Punct => false,
        }
    }

    fn inside(&self, i: usize, kw: &str) -> Result<(), RapidError> {
        match self.blocks.last() {
            Some((k, _)) if *k == kw => Ok(()),
            _ => Err(self.err(i, format!("`{}` outside a {kw} block", self.text(i)))),
        }
    }

    fn close_block(&mut self, i: usize, kw: &str) -> Result<(), RapidError> {
        match self.blocks.last().copied() {
            Some((k, _)) if k == kw => {
                self.blocks.pop();
                if matches!(kw, "PROC" | "FUNC" | "TRAP" | "RECORD") {
                    self.routine = None;
                }
                self.i = i + 1;
                Ok(())
            }
            Some((k, line)) => Err(self.err(
                i,
                format!(
                    "{} while the {k} opened on line {line} is not closed (missing END{k}?)",
                    self.text(i)
                ),
            )),
            None => Err(self.err(i, format!("{} without {kw}", self.text(i)))),
        }
    }

    /// Index of the first of `words` from `k` at bracket depth 0 before the next `;` (None
    /// when `;` comes first and `stop_at_semicolon`).
    fn find(
        &self,
        mut k: usize,
        words: &[&str],
        stop_at_semicolon: bool,
    ) -> Result<Option<usize>, RapidError> {
        let mut depth = 0i32;
        while k < self.t.len() {
            let tk = self.t[k];
            if tk.kind == Tok::Punct {
                match self.text(k) {
                    "(" | "[" | "{" => depth += 1,
                    ")" | "]" | "}" => depth -= 1,
                    ";" if depth == 0 => {
                        if stop_at_semicolon {
                            return Ok(None);
                        }
                        return Err(self.err(k, format!("expected {} before `;`", words[0])));
                    }
                    _ => {}
                }
            } else if depth == 0 && words.iter().any(|w| tk.is(self.src, w)) {
                return Ok(Some(k));
            }
            k += 1;
        }
        Err(self.err(
            k,
            format!("expected {} before the end of the file", words[0]),
        ))
    }

    /// The index of the bracket closing the one at `open`.
    fn close(&self, open: usize) -> Result<usize, RapidError> {
        let mut stack: Vec<usize> = Vec::new();
        let mut k = open;
        while k < self.t.len() {
            if self.t[k].kind == Tok::Punct {
                let s = self.text(k);
                match s {
                    "(" | "[" | "{" => stack.push(k),
                    ")" | "]" | "}" => {
                        let Some(o) = stack.pop() else {
                            return Err(self.err(k, format!("`{s}` without its opening bracket")));
                        };
                        let want = match self.text(o) {
                            "(" => ")",
                            "[" => "]",
                            _ => "}",
                        };
                        if s != want {
                            return Err(self.err(
                                k,
                                format!(
                                    "`{s}` closes the `{}` opened on line {}",
                                    self.text(o),
                                    self.line(o)
                                ),
                            ));
                        }
                        if stack.is_empty() {
                            return Ok(k);
                        }
                    }
                    ";" => {
                        let o = stack.last().copied().unwrap_or(open);
                        return Err(self.err(
                            o,
                            format!(
                                "`{}` is not closed before `;` (line {})",
                                self.text(o),
                                self.line(k)
                            ),
                        ));
                    }
                    _ => {}
                }
            }
            k += 1;
        }
        Err(self.err(open, format!("`{}` is never closed", self.text(open))))
    }

    /// A statement from `self.i` to its `;`: brackets checked, then read as a declaration
    /// or a move instruction if it is one.
    fn statement(&mut self) -> Result<(), RapidError> {
        let s = self.i;
        let mut k = s;
        let mut stack: Vec<usize> = Vec::new();
        loop {
            let Some(tk) = self.t.get(k) else {
                return Err(self.err(s, "statement not ended by `;` before the end of the file"));
            };
            if tk.kind == Tok::Ident
                && stack.is_empty()
                && k > s
                && !(k == s + 1 && (self.is(s, "LOCAL") || self.is(s, "TASK")))
                && BLOCK_WORDS.iter().any(|w| tk.is(self.src, w))
            {
                return Err(self.err(
                    s,
                    format!("statement not ended by `;` before {}", self.text(k)),
                ));
            }
            // Two operands in a row (`x := 1 y := 2;`): a `;` is missing after the first.
            // The first pair may be a call and its argument (`MoveL p1, ..`).
            if k > s + 1 && stack.is_empty() && self.operand(k) && self.operand(k - 1) {
                let declaration = ["LOCAL", "TASK", "CONST", "PERS", "VAR"]
                    .iter()
                    .any(|w| self.is(s, w));
                if !declaration && !self.is(s, "IF") {
                    return Err(self.err(
                        k - 1,
                        format!(
                            "`;` or an operator missing between `{}` and `{}`",
                            self.text(k - 1),
                            self.text(k)
                        ),
                    ));
                }
            }
            if tk.kind == Tok::Punct {
                match self.text(k) {
                    "(" | "[" | "{" => stack.push(k),
                    ")" | "]" | "}" => {
                        let c = self.text(k);
                        let Some(o) = stack.pop() else {
                            return Err(self.err(k, format!("`{c}` without its opening bracket")));
                        };
                        let want = match self.text(o) {
                            "(" => ")",
                            "[" => "]",
                            _ => "}",
                        };
                        if c != want {
                            return Err(self.err(
                                k,
                                format!(
                                    "`{c}` closes the `{}` opened on line {}",
                                    self.text(o),
                                    self.line(o)
                                ),
                            ));
                        }
                    }
                    ";" => {
                        if let Some(&o) = stack.last() {
                            return Err(self.err(
                                o,
                                format!(
                                    "`{}` is not closed before the `;` on line {}",
                                    self.text(o),
                                    self.line(k)
                                ),
                            ));
                        }
                        break;
                    }
                    _ => {}
                }
            }
            k += 1;
        }
        self.i = k + 1;
        let first = s + usize::from(self.is(s, "LOCAL") || self.is(s, "TASK"));
        if ["CONST", "PERS", "VAR"].iter().any(|w| self.is(first, w)) {
            self.declaration(s, first, k)
        } else {
            self.move_use(s, k);
            Ok(())
        }
    }

    fn declaration(&mut self, s: usize, first: usize, semi: usize) -> Result<(), RapidError> {
        let storage = self.text(first).to_string();
        let ty = self.ident(first + 1, "a data type")?.to_ascii_lowercase();
        let name = self.ident(first + 2, "a data name")?;
        let mut k = first + 3;
        let mut dims = Vec::new();
        if self.is_punct(k, "{") {
            let close = self.close(k)?;
            for part in self.t[k + 1..close].split(|t| t.is_punct(self.src, ",")) {
                let n = match part {
                    [t] if t.kind == Tok::Num => t.text(self.src).parse::<usize>().ok(),
                    _ => None,
                };
                dims.push(n);
            }
            k = close + 1;
        }
        let value_span = self
            .is_punct(k, ":=")
            .then(|| (self.t[k + 1].start, self.t[semi - 1].end));
        let value = if self.is_punct(k, ":=") {
            let (v, next) = self.value(k + 1, semi)?;
            if next != semi {
                return Err(self.err(
                    next,
                    format!("unexpected `{}` in the value of {name}", self.text(next)),
                ));
            }
            Some(v)
        } else if k != semi {
            return Err(self.err(
                k,
                format!(
                    "expected `:=` or `;` after {name}, found `{}`",
                    self.text(k)
                ),
            ));
        } else {
            None
        };
        self.decls.push(Decl {
            line: self.t[s].line,
            storage,
            ty,
            name,
            dims,
            value,
            start: self.t[s].start,
            end: self.t[semi].end,
            ty_span: (self.t[first + 1].start, self.t[first + 1].end),
            name_span: (self.t[first + 2].start, self.t[first + 2].end),
            value_span,
            routine: self.routine.clone(),
        });
        Ok(())
    }

    /// A value from `k` (before `end`): the value and the index after it.
    fn value(&self, k: usize, end: usize) -> Result<(Value, usize), RapidError> {
        if k >= end {
            return Err(self.err(k.min(end), "a value is missing"));
        }
        if self.is_punct(k, "[") {
            let mut items = Vec::new();
            let mut j = k + 1;
            if self.is_punct(j, "]") {
                return Err(self.err(j, "empty `[]`"));
            }
            loop {
                let (v, next) = self.value(j, end)?;
                items.push(v);
                if self.is_punct(next, ",") {
                    j = next + 1;
                } else if self.is_punct(next, "]") {
                    return Ok((
                        Value::List {
                            items,
                            start: self.t[k].start,
                            end: self.t[next].end,
                        },
                        next + 1,
                    ));
                } else {
                    return Err(self.err(
                        next,
                        format!("expected `,` or `]`, found `{}`", self.text(next.min(end))),
                    ));
                }
            }
        }
        // Up to the next `,` or `]` at depth 0.
        let mut j = k;
        let mut depth = 0i32;
        while j < end {
            if self.t[j].kind == Tok::Punct {
                match self.text(j) {
                    "(" | "[" | "{" => depth += 1,
                    ")" | "}" => depth -= 1,
                    "]" if depth == 0 => break,
                    "]" => depth -= 1,
                    "," if depth == 0 => break,
                    _ => {}
                }
            }
            j += 1;
        }
        let span = &self.t[k..j];
        let v = match span {
            [n] if n.kind == Tok::Num => number(self.src, n.start, n),
            [sg, n]
                if n.kind == Tok::Num
                    && (sg.is_punct(self.src, "-") || sg.is_punct(self.src, "+")) =>
            {
                let mut v = number(self.src, sg.start, n);
                if let Value::Num { v: x, .. } = &mut v
                    && sg.is_punct(self.src, "-")
                {
                    *x = -*x;
                }
                v
            }
            [w] if matches!(w.kind, Tok::Ident | Tok::Str) => {
                Value::Word(w.text(self.src).to_string())
            }
            _ => Value::Expr,
        };
        Ok((v, j))
    }

    /// Record a move instruction `s..semi` if it is one.
    fn move_use(&mut self, s: usize, semi: usize) {
        let Some(&(_, points, tool_at)) = MOVES.iter().find(|(n, _, _)| self.is(s, n)) else {
            return;
        };
        // Split the arguments at `,` and `\` at depth 0.
        let mut args: Vec<(bool, usize, usize)> = Vec::new();
        let mut depth = 0i32;
        let mut start = s + 1;
        let mut optional = self.is_punct(start, "\\");
        if optional {
            start += 1;
        }
        let mut k = start;
        while k <= semi {
            let sep =
                k == semi || (depth == 0 && (self.is_punct(k, ",") || self.is_punct(k, "\\")));
            if sep {
                args.push((optional, start, k));
                if k == semi {
                    break;
                }
                optional = self.is_punct(k, "\\") || self.is_punct(k + 1, "\\");
                start = if self.is_punct(k, ",") && self.is_punct(k + 1, "\\") {
                    k + 2
                } else {
                    k + 1
                };
                k = start;
                continue;
            }
            match self.text(k) {
                "(" | "[" | "{" => depth += 1,
                ")" | "]" | "}" => depth -= 1,
                _ => {}
            }
            k += 1;
        }
        let required: Vec<(usize, usize)> =
            args.iter().filter(|a| !a.0).map(|a| (a.1, a.2)).collect();
        let targets = points
            .iter()
            .filter_map(|&p| required.get(p))
            .filter_map(|&(a, b)| self.target_name(a, b))
            .collect();
        let tool = required
            .get(tool_at)
            .and_then(|&(a, b)| self.data_name(a, b));
        let wobj = args
            .iter()
            .filter(|a| a.0 && self.is(a.1, "WObj") && self.is_punct(a.1 + 1, ":="))
            .find_map(|a| self.data_name(a.1 + 2, a.2));
        self.moves.push(MoveUse {
            line: self.t[s].line,
            instruction: self.text(s).to_string(),
            targets,
            tool,
            wobj,
        });
    }

    /// `name` or `name{..}` spanning `a..b`.
    fn data_name(&self, a: usize, b: usize) -> Option<String> {
        let t = self.t.get(a).filter(|t| t.kind == Tok::Ident)?;
        let whole = b == a + 1 || (self.is_punct(a + 1, "{") && self.close(a + 1).ok()? + 1 == b);
        whole.then(|| t.text(self.src).to_string())
    }

    /// The robtarget an argument moves to: `p`, `p{i}`, or `Offs(p, ..)` / `RelTool(p, ..)`.
    fn target_name(&self, a: usize, b: usize) -> Option<(String, bool)> {
        if let Some(n) = self.data_name(a, b) {
            return Some((n, false));
        }
        let through = (self.is(a, "Offs") || self.is(a, "RelTool")) && self.is_punct(a + 1, "(");
        if !through {
            return None;
        }
        let t = self.t.get(a + 2).filter(|t| t.kind == Tok::Ident)?;
        Some((t.text(self.src).to_string(), true))
    }
}

fn keyword(up: &str) -> &'static str {
    match up {
        "PROC" => "PROC",
        "FUNC" => "FUNC",
        "TRAP" => "TRAP",
        "RECORD" => "RECORD",
        "FOR" => "FOR",
        _ => "WHILE",
    }
}

fn number(src: &str, start: usize, n: &Token) -> Value {
    match n.text(src).parse::<f64>() {
        Ok(v) => Value::Num {
            v,
            start,
            end: n.end,
        },
        Err(_) => Value::Expr,
    }
}
