// The login form, shown in place of any view when the API answers 401 (auth is on and there is no session).
import { postJSON } from "../api.js";
import { clearError, field, h, page, say, showError } from "../ui.js";

/** `onDone(me)` runs after a successful login (the app re-renders the page that asked for it). */
export function loginView(onDone) {
  return (container) => {
    const username = field("Username", h("input", { type: "text", autocomplete: "username", required: true }));
    const password = field("Password", h("input", { type: "password", autocomplete: "current-password", required: true }));
    const form = h(
      "form",
      {
        class: "card narrow",
        onsubmit: async (event) => {
          event.preventDefault();
          try {
            const me = await postJSON("auth/login", { username: username.input.value, password: password.input.value });
            clearError();
            say(`Logged in as ${me.username}.`);
            onDone(me);
          } catch (error) {
            showError(error, "log in");
            password.input.select();
          }
        },
      },
      h("p", {}, "This server needs an account. Ask an admin for one (fringelab user add)."),
      username.wrap,
      password.wrap,
      h("button", { type: "submit", class: "primary" }, "Log in"),
    );
    page(container, "Log in", form);
    username.input.focus();
  };
}
