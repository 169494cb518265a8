// "API tokens": tokens for scripts (create: the secret is shown once; list; revoke).
import { deleteJSON, getJSON, postJSON } from "../api.js";
import { attempt, field, formatTime, h, page, say, showError, table } from "../ui.js";

export async function renderTokens(container, _params, context) {
  const me = await attempt("ask who you are", () => getJSON("auth/me"));
  if (!me || !context.current()) return;
  if (!me.auth_enabled) {
    page(
      container,
      "API tokens",
      h(
        "p",
        {},
        "Accounts are off on this server (FRINGELAB_AUTH_ENABLED=false): scripts use the API without a token. ",
        "Turn accounts on to give each script its own token.",
      ),
    );
    return;
  }
  const list = h("div", {});
  const secret = h("div", { "aria-live": "polite" });
  const name = field("Token name", h("input", { type: "text", required: true, maxlength: 100, placeholder: "nightly upload script" }));
  const days = field("Expires after (days)", h("input", { type: "number", min: 1, max: 3650, placeholder: "never" }), "Empty: never expires.");

  const refresh = async () => {
    const tokens = await attempt("list your API tokens", () => getJSON("auth/tokens"));
    if (!tokens || !context.current()) return;
    list.replaceChildren(
      table(
        "Your API tokens",
        [
          { title: "Name", value: (t) => t.name },
          { title: "Starts with", value: (t) => h("code", {}, t.prefix) },
          { title: "Created", value: (t) => formatTime(t.created_at) },
          { title: "Expires", value: (t) => (t.expires_at ? formatTime(t.expires_at) : "never") },
          { title: "Last used", value: (t) => formatTime(t.last_used_at) },
          {
            title: "State",
            value: (t) =>
              t.revoked_at
                ? `revoked ${formatTime(t.revoked_at)}`
                : h("button", { type: "button", "aria-label": `Revoke token ${t.name}`, onclick: () => revoke(t) }, "Revoke"),
          },
        ],
        tokens,
        { empty: "You have no API tokens." },
      ),
    );
  };
  const revoke = async (token) => {
    if (!window.confirm(`Revoke the token "${token.name}"? Scripts using it stop working at once.`)) return;
    try {
      await deleteJSON(`auth/tokens/${token.id}`);
      say(`Token ${token.name} revoked.`);
      await refresh();
    } catch (error) {
      showError(error, "revoke the token");
    }
  };
  const form = h(
    "form",
    {
      class: "card grid-form",
      "aria-label": "New API token",
      onsubmit: async (event) => {
        event.preventDefault();
        try {
          const body = { name: name.input.value };
          if (days.input.value) body.expires_in_days = Number(days.input.value);
          const created = await postJSON("auth/tokens", body);
          secret.replaceChildren(
            h(
              "div",
              { class: "card secret" },
              h("p", {}, `Token "${created.name}" created. Copy it now: it is shown only once.`),
              h("input", { type: "text", readonly: true, value: created.token, "aria-label": "New token secret", onfocus: (e) => e.target.select() }),
            ),
          );
          name.input.value = "";
          say(`Token ${created.name} created.`);
          await refresh();
        } catch (error) {
          showError(error, "create the token");
        }
      },
    },
    name.wrap,
    days.wrap,
    h("button", { type: "submit", class: "primary" }, "Create token"),
  );
  page(
    container,
    "API tokens",
    h("p", {}, "Scripts send a token as ", h("code", {}, "Authorization: Bearer flb_…"), ". Logged in as ", me.username, "."),
    form,
    secret,
    list,
  );
  await refresh();
}
