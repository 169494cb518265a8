// Help: the method documentation of docs/ (rendered to HTML by the server, GET /api/v1/docs/{name}), readable in
// the dashboard offline. Reports link to it with ?section=<heading id>&find=<term>: the page opens at that
// section and marks the first place after it where the term is explained.
import { getJSON } from "../api.js";
import { attempt, h, page } from "../ui.js";

export async function renderHelpIndex(container, _params, context) {
  const docs = await attempt("list the documentation", () => getJSON("docs"));
  if (!docs || !context.current()) return;
  page(container, "Help", h("p", {}, "How fringelab measures, what its numbers mean and what its files hold."),
    h("ul", { "aria-label": "Documents" }, docs.map((doc) => h("li", {}, h("a", { href: `#/help/${doc.name}` }, doc.title)))));
}

/** The first element after `start` (in document order) whose text holds `term`, innermost: a <code>, a cell. */
function findAfter(root, start, term) {
  const candidates = [...root.querySelectorAll("code, td, li, p")];
  const begin = start ? candidates.findIndex((el) => start.compareDocumentPosition(el) & Node.DOCUMENT_POSITION_FOLLOWING) : 0;
  const ordered = begin < 0 ? candidates : [...candidates.slice(begin), ...candidates.slice(0, begin)];
  const needle = term.toLowerCase();
  return ordered.find((el) => el.textContent.toLowerCase().includes(needle)) || null;
}

export async function renderHelp(container, { name }, context) {
  const doc = await attempt(`read ${name}`, () => getJSON(`docs/${name}`));
  if (!doc || !context.current()) return;
  const body = h("article", { class: "doc", "aria-label": doc.title });
  // The server renders our own docs/*.md with raw HTML disabled: this HTML is not user input.
  body.innerHTML = doc.html;
  const contents = h("nav", { class: "doc-contents", "aria-label": "Sections" }, h("h2", {}, "Contents"),
    h("ul", {}, doc.sections.filter((_, i) => i > 0).map((s) => h("li", {}, h("a", { href: `#/help/${name}?section=${s.id}` }, s.title)))));
  page(container, doc.title, h("p", {}, h("a", { href: "#/help" }, "All documents")), h("div", { class: "doc-layout" }, contents, body));
  document.title = `${doc.title} · fringelab`;
  body.querySelector("h1")?.remove(); // the page's own heading says it
  const section = context.query.get("section");
  const term = context.query.get("find");
  const heading = section ? body.querySelector(`[id="${CSS.escape(section)}"]`) : null;
  const found = term ? findAfter(body, heading, term) : null;
  if (found) {
    found.classList.add("found");
    found.setAttribute("tabindex", "-1");
    found.scrollIntoView({ block: "center" });
    found.focus({ preventScroll: true });
  } else if (heading) {
    heading.scrollIntoView({ block: "start" });
  }
}
