// The hash router: "#/experiments/3" → the view registered for "/experiments/:id" with { id: "3" }.
// A view is `render(container, params, context)`; `context.onLeave(fn)` registers clean-up (close an event
// stream, stop a timer) that runs when the user navigates away, and `context.current()` says whether the view
// is still the one shown (async work that finishes late must not draw over the next view).

export class Router {
  constructor(container, { notFound, onChange = () => {} }) {
    this.container = container;
    this.routes = [];
    this.notFound = notFound;
    this.onChange = onChange;
    this.leaveHandlers = [];
    this.generation = 0;
    window.addEventListener("hashchange", () => this.show());
  }

  add(pattern, view) {
    const names = [];
    const source = pattern.replace(/:(\w+)/g, (_, name) => {
      names.push(name);
      return "([^/]+)";
    });
    this.routes.push({ regex: new RegExp(`^${source}$`), names, view });
    return this;
  }

  /** The path and query of the current hash: "#/jobs?kind=topography" → ["/jobs", URLSearchParams]. */
  location() {
    const raw = window.location.hash.replace(/^#/, "") || "/";
    const [path, search = ""] = raw.split("?");
    return [path, new URLSearchParams(search)];
  }

  leave() {
    for (const handler of this.leaveHandlers.splice(0)) {
      try {
        handler();
      } catch (error) {
        console.warn("clean-up of the previous view failed", error);
      }
    }
  }

  /** Render the view of the current hash (again). */
  show() {
    this.leave();
    this.generation += 1;
    const generation = this.generation;
    const [path, search] = this.location();
    const context = {
      query: search,
      onLeave: (handler) => this.leaveHandlers.push(handler),
      current: () => generation === this.generation,
    };
    this.onChange(path);
    for (const route of this.routes) {
      const match = route.regex.exec(path);
      if (match) {
        const params = Object.fromEntries(route.names.map((name, i) => [name, decodeURIComponent(match[i + 1])]));
        return route.view(this.container, params, context);
      }
    }
    return this.notFound(this.container, { path }, context);
  }

  /** Render an arbitrary view in place (the login form) without changing the hash. */
  showInstead(view) {
    this.leave();
    this.generation += 1;
    const generation = this.generation;
    return view(this.container, {}, {
      query: new URLSearchParams(),
      onLeave: (handler) => this.leaveHandlers.push(handler),
      current: () => generation === this.generation,
    });
  }
}
